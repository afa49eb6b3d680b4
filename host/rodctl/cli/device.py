"""Talking to the board: status, log, arm, disarm, clear-fault, set, console, sim-device, log-convert."""

from __future__ import annotations

import argparse
import contextlib
import datetime as _dt
import json
import math
import os
import shlex
import signal
import sys
import threading
import time
from pathlib import Path

from rodgains.errors import UserError

from rodctl.link import protocol as P
from rodctl.link.session import (SETTINGS, Session, hello_settings, is_tty, name_of, parse_assignment,
                   reason_text)

PORT_HELP = ("serial port (e.g. /dev/ttyACM0), any pyserial URL, or sim:// for the simulated rod "
             "(sim://?plant=der&edges=20&params=FILE); default: the one Teensy on USB (16C0:0483)")
ARM_CHOICES = {"swing-up": P.ArmMode.SWING_UP, "balance": P.ArmMode.BALANCE}


def add_port_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--port", metavar="PORT", help=PORT_HELP)


def add_design_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--params", metavar="FILE",
                   help="parameter file the firmware may have been built from (identifies the design by its hash)")
    p.add_argument("--set", metavar="SECTION.KEY=VALUE", action="append", default=[], dest="overrides",
                   help="override one parameter of --params (repeatable)")


def design_params(session: Session, args=None):
    """(Params, source) the firmware's gains came from, matched by the HELLO's header hash."""
    from rodctl.logs.logfile import identify_params

    cands = []
    if args is not None and (getattr(args, "params", None) or getattr(args, "overrides", None)):
        from rodgains.params import load_params

        label = args.params or "defaults"
        if args.overrides:
            label += " with " + " ".join(f"--set {o}" for o in args.overrides)
        cands.append((load_params(args.params, args.overrides), label))
    dev = getattr(session.ser, "device", None)  # sim://: the virtual board knows its parameters
    if dev is not None and getattr(dev, "params", None) is not None:
        from rodctl.logs.logfile import _shown
        from rodgains.params import DEFAULT_PARAMS

        cands.append((dev.params, f"{_shown(dev.params_path or DEFAULT_PARAMS)} (sim://)"))
    return identify_params(bytes(session.hello.header_sha256).hex(), cands)


# ---- status line --------------------------------------------------------------------------------

class StatusLine:
    """One live line on stderr (~4 updates/s on a terminal; a plain line per second otherwise)."""

    def __init__(self, stream=None, tty: bool | None = None):
        self.stream = stream or sys.stderr
        self.tty = is_tty(self.stream) if tty is None else tty
        self.interval = 0.25 if self.tty else 1.0
        self._last = 0.0
        self._shown = False

    def due(self) -> bool:
        return time.monotonic() - self._last >= self.interval

    def update(self, text: str, force: bool = False) -> None:
        if not force and not self.due():
            return
        self._last = time.monotonic()
        try:
            if self.tty:
                self.stream.write("\r\x1b[K" + text)
                self._shown = True
            else:
                self.stream.write(text + "\n")
            self.stream.flush()
        except (OSError, ValueError):
            pass

    def end(self) -> None:
        if self.tty and self._shown:
            try:
                self.stream.write("\n")
                self.stream.flush()
            except (OSError, ValueError):
                pass
            self._shown = False


class RateMeter:
    """Frames per second over the last second or so."""

    def __init__(self, frames: int = 0):
        self._hist: list[tuple[float, int]] = [(time.monotonic(), frames)]

    def rate(self, frames: int) -> float:
        now = time.monotonic()
        self._hist.append((now, frames))
        while len(self._hist) > 2 and now - self._hist[0][0] > 1.0:
            self._hist.pop(0)
        t0, f0 = self._hist[0]
        return (frames - f0) / (now - t0) if now > t0 else 0.0


def mode_text(mode, reason) -> str:
    m = name_of(P.Mode, mode)
    if int(mode) == P.Mode.FAULT:
        return f"{m} ({reason_text(reason)}: run clear-fault)"
    if int(reason) != P.Reason.NONE:
        return f"{m} (last: {reason_text(reason)})"
    return m


def status_text(s: Session, fps: float, rows: int | None = None) -> str:
    c = s.counters()
    t = s.telemetry
    parts = [f"{s.elapsed():6.1f} s", f"{fps:6.0f} frames/s", f"CRC errors {c['crc_errors']}",
             f"seq gaps {c['seq_gaps']}", f"device dropped {c['device_dropped']}"]
    if t is not None:
        parts.append(f"mode {mode_text(t.mode, t.reason)}")
        if t.n:
            parts.append(f"theta1 {math.degrees(t.theta_hat[0]):7.1f} deg")
    if rows is not None:
        parts.append(f"{rows} rows")
    return " | ".join(parts)


# ---- signals ------------------------------------------------------------------------------------

@contextlib.contextmanager
def stop_signals():
    """SIGTERM and SIGHUP stop like Ctrl-C (KeyboardInterrupt in the main thread)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def raise_interrupt(signum, frame):
        raise KeyboardInterrupt

    old = {}
    for sig in (signal.SIGTERM, getattr(signal, "SIGHUP", None)):
        if sig is not None:
            old[sig] = signal.signal(sig, raise_interrupt)
    try:
        yield
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)


@contextlib.contextmanager
def no_interrupts():
    """Let cleanup finish: a second Ctrl-C (or SIGTERM) waits until the block is done."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    got = []
    handlers = {}
    for sig in (signal.SIGINT, signal.SIGTERM, getattr(signal, "SIGHUP", None)):
        if sig is not None:
            handlers[sig] = signal.signal(sig, lambda s, f: got.append(s))
    try:
        yield
    finally:
        for sig, h in handlers.items():
            signal.signal(sig, h)


def open_session(args) -> Session:
    return Session(getattr(args, "port", None))


# ---- streaming (log, arm) ------------------------------------------------------------------------

def default_log_name(fmt: str) -> str:
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    return f"rod-{stamp}.{'parquet' if fmt == 'parquet' else 'csv'}"


def stream(args, arm_mode=None, out: str | None = None, what: str = "log") -> int:
    """Stay attached: optional arm, optional log, a status line, until Ctrl-C / --duration / error."""
    from rodctl.logs.logfile import LogWriter, device_metadata, log_format, require_pyarrow

    fmt = None
    if out is not None:
        fmt = log_format(out, getattr(args, "format", None))
        if fmt == "parquet":
            require_pyarrow()  # before touching the board
    duration = getattr(args, "duration", None)
    if duration is not None and not duration > 0:
        raise UserError("--duration must be positive")
    session = Session(args.port)
    writer = None
    status = StatusLine()
    meter = RateMeter()
    ended = "duration" if duration is not None else "end"
    error: BaseException | None = None
    with stop_signals():
        try:
            session.open()
            meter = RateMeter(session.frames)
            h = session.hello
            params, source = design_params(session, args)
            if out is not None:
                meta = device_metadata(h, port=session.port, params=params, params_source=source,
                                       start_unix=session.open_unix)
                writer = LogWriter(out, meta, n=h.n, fmt=fmt)
                session.add_listener(writer, replay=True)
            design = (f"parameters {source}" if params is not None
                      else f"parameters unknown (header {bytes(h.header_sha256).hex()[:16]})")
            target = f" -> {writer.path}" if writer else ""
            print(f"{what}: {session.port}{target}  (firmware {h.fw_major}.{h.fw_minor}.{h.fw_patch}, N={h.n}, "
                  f"{1e6 / h.period_us:g} Hz, {design}); Ctrl-C stops" + (" and disarms" if arm_mode else ""),
                  file=sys.stderr, flush=True)
            if arm_mode is not None:
                ack = session.arm(arm_mode)
                print(f"armed {arm_mode.name.lower().replace('_', '-')}: mode {name_of(P.Mode, ack.mode)}",
                      file=sys.stderr, flush=True)
            t_end = None if duration is None else time.monotonic() + duration
            while t_end is None or time.monotonic() < t_end:
                time.sleep(0.05)
                session.check()
                if session.listener_error is not None:
                    e = session.listener_error
                    raise UserError(f"writing {out} failed: {getattr(e, 'strerror', None) or e}")
                if writer is not None:
                    writer.maybe_flush()
                if status.due():
                    status.update(status_text(session, meter.rate(session.frames),
                                              writer.rows if writer else None))
        except KeyboardInterrupt:
            ended = "Ctrl-C"
        except BaseException as e:  # noqa: BLE001 - file first, then the error
            ended = "error"
            error = e
        finally:
            with no_interrupts():
                status.end()
                session.close()  # DISARM when possible; every frame received is in the writer now
                c = session.counters()
                if writer is not None:
                    session.remove_listener(writer)
                    trailer = {"end": ended, "frames": c["frames"], "seq_gaps": c["seq_gaps"],
                               "crc_errors": c["crc_errors"], "decode_errors": c["errors"],
                               "device_frames_dropped": c["device_dropped"],
                               "device_frames_dropped_since_boot": c["device_dropped_boot"],
                               "sync_bytes": session.sync_bytes}
                    if session.disconnected:
                        trailer["disconnected"] = session.disconnected
                    try:
                        writer.close(trailer)
                    except UserError as e:
                        error = error or e
                    except OSError as e:
                        error = error or UserError(f"closing {writer.path} failed: {e}")
    if writer is not None:
        print(f"wrote {writer.path}: {writer.rows} rows = {c['frames']} frames ({writer.telemetry_rows} telemetry); "
              f"seq gaps {c['seq_gaps']}, CRC errors {c['crc_errors']}, device dropped {c['device_dropped']}"
              + _disarm_note(session),
              file=sys.stderr, flush=True)
    elif session.hello is not None and ended != "error":
        print(f"{what} ended ({ended}): {c['frames']} frames, seq gaps {c['seq_gaps']}, "
              f"CRC errors {c['crc_errors']}" + _disarm_note(session),
              file=sys.stderr, flush=True)
    if error is not None:
        raise error
    return 0


def _disarm_note(session: Session) -> str:
    if session.disarm_acked:
        return "; disarmed"
    if session.disconnected is not None:
        return "; link lost, not disarmed (the board's watchdog disarms it)"
    return "; disarm not confirmed (the board's watchdog disarms it)"


def run_log(args) -> int:
    fmt = args.format
    out = args.out or default_log_name(fmt or "csv")
    arm = ARM_CHOICES[args.arm] if args.arm else None
    return stream(args, arm_mode=arm, out=out, what="log")


def run_arm(args) -> int:
    mode = P.ArmMode.SWING_UP if args.swing_up else P.ArmMode.BALANCE
    return stream(args, arm_mode=mode, out=args.out, what="arm")


# ---- one-shot commands ---------------------------------------------------------------------------

def status_report(session: Session, args=None) -> dict:
    h = session.hello
    t = session.wait_telemetry(timeout=2.0)
    params, source = design_params(session, args)
    return {
        "port": session.port,
        "firmware_version": f"{h.fw_major}.{h.fw_minor}.{h.fw_patch}",
        "gains_schema": h.gains_schema,
        "protocol_version": P.VERSION,
        "header_sha256": bytes(h.header_sha256).hex(),
        "params_source": source if params is not None else "unknown",
        "n": h.n,
        "rate_hz": 1e6 / h.period_us,
        "decimation": h.decimation,
        "settings": hello_settings(h),
        "torque_max_Nm": h.torque_max,
        "mode": name_of(P.Mode, t.mode),
        "reason": name_of(P.Reason, t.reason),
        "flags": [f.name for f in P.TelemetryFlag if int(t.flags) & int(f)],
        "encoder_count": t.encoder_count,
        "theta_hat_rad": list(t.theta_hat),
        "rate_hat_rad_s": list(t.rate_hat),
        "base_rate_rad_s": t.base_rate,
        "torque_Nm": t.torque,
        "duty": t.duty,
        "overruns": t.overruns,
        "frames_dropped": t.frames_dropped,
        "rx_errors": t.rx_errors,
    }


def run_status(args) -> int:
    with stop_signals(), Session(args.port) as s:
        r = status_report(s, args)
    if args.json:
        print(json.dumps(r, indent=1))
        return 0
    st = r["settings"]
    mode = r["mode"] + (f" ({reason_text(P.Reason[r['reason']])})" if r["reason"] != "NONE" else "")
    if r["mode"] == "FAULT":
        mode += ": run `rodctl clear-fault`"
    print(f"port        {r['port']}")
    print(f"firmware    {r['firmware_version']} (gains schema {r['gains_schema']}), protocol v{r['protocol_version']}")
    print(f"gains       N={r['n']} at {r['rate_hz']:g} Hz, header sha256 {r['header_sha256'][:16]}..., "
          f"parameters {r['params_source']}")
    print(f"mode        {mode}; flags {', '.join(r['flags']) or 'none'}")
    print(f"settings    swing_amplitude {st['swing_amplitude']:.4g} N m, swing_angle_deg {st['swing_angle_deg']:.4g}, "
          f"catch_angle_deg {st['catch_angle_deg']:.4g}, telemetry_decimation {st['telemetry_decimation']:g}, "
          f"heartbeat_timeout {st['heartbeat_timeout']:.3g} s (torque max {r['torque_max_Nm']:.3g} N m)")
    th = ", ".join(f"{math.degrees(x):.1f}" for x in r["theta_hat_rad"])
    print(f"telemetry   encoder {r['encoder_count']} counts, theta_hat [{th}] deg, base rate "
          f"{r['base_rate_rad_s']:.3g} rad/s, torque {r['torque_Nm']:.3g} N m, duty {r['duty']:.3g}")
    print(f"counters    overruns {r['overruns']}, frames dropped {r['frames_dropped']}, rx errors {r['rx_errors']}")
    return 0


def run_disarm(args) -> int:
    with stop_signals(), Session(args.port, disarm_on_close=False) as s:
        ack = s.disarm()
        if ack.mode == P.Mode.FAULT:
            print(f"device is in FAULT ({reason_text(s.current_reason())}), driver off; "
                  "run `rodctl clear-fault` to return to DISARMED")
        else:
            print(f"disarmed: mode {name_of(P.Mode, ack.mode)}")
    return 0


def run_clear_fault(args) -> int:
    with stop_signals(), Session(args.port) as s:
        before = s.wait_telemetry(timeout=2.0)
        ack = s.clear_fault()
        if before.mode == P.Mode.FAULT:
            print(f"fault cleared ({reason_text(before.reason)}): mode {name_of(P.Mode, ack.mode)}")
        else:
            print(f"no fault to clear: mode {name_of(P.Mode, ack.mode)}")
    return 0


def apply_settings(s: Session, assignments: list[str], args=None, out=print) -> None:
    parsed = [parse_assignment(a) for a in assignments]  # all names checked before anything is sent
    params, _ = design_params(s, args)  # for the catch angle's range (the balance angle limit)
    for setting, value in parsed:
        s.set(setting, value, design_params=params)
    h = s.request_hello()
    now = hello_settings(h)
    for setting, value in parsed:
        out(f"{setting.name} = {setting.format(now[setting.name])} (until the board resets)")


def run_set(args) -> int:
    for a in args.assignments:
        parse_assignment(a)
    with stop_signals(), Session(args.port) as s:
        apply_settings(s, args.assignments, args)
    return 0


# ---- console --------------------------------------------------------------------------------------

CONSOLE_HELP = """commands:
  arm swing-up | arm balance   arm the controller (disarmed again when the console closes)
  disarm                       driver off (DISARMED, reason HOST)
  clear                        leave FAULT for DISARMED (clear-fault)
  set NAME=VALUE ...           names: """ + ", ".join(SETTINGS) + """
  status                       firmware, settings, mode, one telemetry frame
  quit                         disarm and leave (also Ctrl-D, Ctrl-C)"""


class _LiveLine(threading.Thread):
    """On a terminal: keeps the line above the prompt showing the live status."""

    def __init__(self, session: Session, stream):
        super().__init__(daemon=True, name="rodctl-console-status")
        self.session = session
        self.stream = stream
        self.meter = RateMeter(session.frames)
        self.stop = threading.Event()
        self.paused = threading.Event()

    def text(self) -> str:
        return status_text(self.session, self.meter.rate(self.session.frames))

    def run(self) -> None:
        while not self.stop.wait(0.25):
            if self.paused.is_set() or not self.session.alive:
                continue
            try:
                # save cursor, up one line, clear it, write, restore cursor
                self.stream.write("\x1b7\x1b[1A\r\x1b[2K" + self.text() + "\x1b8")
                self.stream.flush()
            except (OSError, ValueError):
                return


def run_console(args) -> int:
    tty = sys.stdin.isatty() and is_tty(sys.stdout)
    if tty:
        with contextlib.suppress(ImportError):
            import readline  # noqa: F401 - line editing and history for input()
    with stop_signals(), Session(args.port) as s:
        h = s.hello
        print(f"connected to {s.port}: firmware {h.fw_major}.{h.fw_minor}.{h.fw_patch}, N={h.n}, "
              f"{1e6 / h.period_us:g} Hz. Heartbeat on while the console is open; 'help' lists commands.")
        live = None
        if tty:
            live = _LiveLine(s, sys.stdout)
            live.start()
        try:
            while True:
                if live is not None:
                    live.paused.set()
                    print(live.text())
                    live.paused.clear()
                try:
                    line = input("rodctl> ")
                except EOFError:
                    print()
                    break
                if live is not None:
                    live.paused.set()
                words = shlex.split(line, comments=True) if line.strip() else []
                if not words:
                    continue
                cmd, rest = words[0].lower(), words[1:]
                try:
                    s.check()
                    if cmd in ("quit", "exit", "q"):
                        break
                    elif cmd in ("help", "?"):
                        print(CONSOLE_HELP)
                    elif cmd == "arm":
                        key = (rest[0].lower().lstrip("-") if rest else "")
                        if key not in ARM_CHOICES:
                            raise UserError("arm swing-up | arm balance")
                        ack = s.arm(ARM_CHOICES[key])
                        print(f"armed {key}: mode {name_of(P.Mode, ack.mode)}")
                    elif cmd == "disarm":
                        ack = s.disarm()
                        print(f"mode {name_of(P.Mode, ack.mode)}")
                    elif cmd in ("clear", "clear-fault"):
                        ack = s.clear_fault()
                        print(f"mode {name_of(P.Mode, ack.mode)}")
                    elif cmd == "set":
                        if not rest:
                            raise UserError(f"set NAME=VALUE (names: {', '.join(SETTINGS)})")
                        apply_settings(s, rest, args)
                    elif cmd == "status":
                        r = status_report(s, args)
                        th = ", ".join(f"{math.degrees(x):.1f}" for x in r["theta_hat_rad"])
                        st = ", ".join(f"{k} {SETTINGS[k].format(v)}" for k, v in r["settings"].items())
                        print(f"mode {mode_text(P.Mode[r['mode']], P.Reason[r['reason']])}; theta_hat [{th}] deg; "
                              f"torque {r['torque_Nm']:.3g} N m; duty {r['duty']:.3g}")
                        print(f"settings: {st}")
                        print(f"firmware {r['firmware_version']}, N={r['n']}, {r['rate_hz']:g} Hz, parameters "
                              f"{r['params_source']}; {status_text(s, 0).split(' | ', 2)[2]}")
                    else:
                        raise UserError(f"unknown command {cmd!r}; 'help' lists them")
                except UserError as e:
                    msg = str(e).replace("run `rodctl clear-fault`", "type `clear`")
                    print(f"error: {msg}")
                    if not s.alive:
                        raise UserError(str(e)) from None
        except KeyboardInterrupt:
            print()
        finally:
            if live is not None:
                live.stop.set()
    print("disarmed and disconnected")
    return 0


# ---- sim-device -----------------------------------------------------------------------------------

def run_sim_device(args) -> int:
    import tty as _tty

    from rodctl.sim.device import RealTimeRunner, VirtualDevice

    if not hasattr(os, "openpty"):
        raise UserError("sim-device --pty needs a POSIX system (pseudo-terminals)")
    dev = VirtualDevice.from_options(plant=args.plant, edges=args.edges, params=args.params)
    master, slave = os.openpty()
    _tty.setraw(slave)  # bytes pass untouched, no echo, for any tool that opens it
    name = os.ttyname(slave)
    os.set_blocking(master, False)
    out_pending = bytearray()

    def take_input() -> bytes:
        chunks = []
        while True:
            try:
                b = os.read(master, 65536)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                break
            if not b:
                break
            chunks.append(b)
        return b"".join(chunks)

    def push() -> None:
        while out_pending:
            try:
                k = os.write(master, out_pending)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                out_pending.clear()
                return
            del out_pending[:k]

    def deliver(data: bytes) -> None:
        out_pending.extend(data)
        push()

    def backlog() -> int:
        push()
        return len(out_pending)

    last = [dev.mode, dev.reason]

    def watch() -> None:
        m, r = dev.mode, dev.reason
        if [m, r] != last:
            print(f"sim-device: t={dev.time:.3f} s: {mode_text(last[0], last[1])} -> {mode_text(m, r)}",
                  file=sys.stderr, flush=True)
            last[:] = [m, r]

    link = None
    if args.link:
        link = Path(args.link)
        if link.is_symlink() or link.exists():
            if not link.is_symlink():
                raise UserError(f"--link {link} exists and is not a symlink")
            link.unlink()
        link.symlink_to(name)
    # What the USB link and the host's serial driver hold unread (like a CDC-ACM port's 64 kB): beyond
    # it the board's own TX buffer fills and it drops frames, counted in telemetry.frames_dropped.
    runner = RealTimeRunner(dev, take_input=take_input, deliver=deliver, backlog=backlog, max_backlog=65536,
                            on_batch=watch, name="sim-device")
    print(f"virtual board: {dev.describe()}", flush=True)
    print(f"connect with: rodctl status --port {link or name}   (Ctrl-C stops the board)", flush=True)
    print(name, flush=True)
    runner.start()
    t_end = None if args.duration is None else time.monotonic() + args.duration
    try:
        with stop_signals():
            while runner.alive and (t_end is None or time.monotonic() < t_end):
                time.sleep(0.1)
    except KeyboardInterrupt:
        pass
    finally:
        runner.stop()
        dev.close()
        for fd in (master, slave):
            with contextlib.suppress(OSError):
                os.close(fd)
        if link is not None:
            with contextlib.suppress(OSError):
                link.unlink()
    if runner.error is not None:
        raise UserError(f"virtual board stopped: {type(runner.error).__name__}: {runner.error}")
    print(f"sim-device: stopped after {dev.time:.1f} s of device time", file=sys.stderr)
    return 0


def run_log_convert(args) -> int:
    from rodctl.logs.logfile import convert_to_parquet

    src = Path(args.journal)
    if not src.exists():
        raise UserError(f"{src}: no such file")
    out = convert_to_parquet(src, args.out)
    print(f"wrote {out}")
    return 0


# ---- registration ---------------------------------------------------------------------------------

def register(sub) -> None:
    p = sub.add_parser("status", help="firmware identity, settings and one telemetry frame",
                       description="Connect, print the HELLO (firmware version, header hash, N, rate, settings) "
                                   "and one telemetry frame, then disarm and disconnect.")
    add_port_arg(p)
    add_design_args(p)
    p.add_argument("--json", action="store_true", help="print as JSON")
    p.set_defaults(func=run_status)

    p = sub.add_parser("log", help="record every frame to CSV or Parquet with a live status line",
                       description="Record every frame the board sends (one row per frame) until Ctrl-C or "
                                   "--duration, with a live status line on stderr. The file is written as frames "
                                   "arrive (flushed 4x per second) and stays readable if the process is killed. "
                                   "On exit the board is disarmed.")
    add_port_arg(p)
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.add_argument("--out", metavar="PATH", help="log file (default rod-YYYYmmdd-HHMMSS.csv)")
    p.add_argument("--format", choices=("csv", "parquet"),
                   help="file format (default: from --out's extension, else csv); parquet needs pyarrow")
    p.add_argument("--arm", choices=sorted(ARM_CHOICES), help="arm the controller after connecting")
    add_design_args(p)
    p.set_defaults(func=run_log)

    p = sub.add_parser("arm", help="arm swing-up or balance and stay attached (Ctrl-C disarms)",
                       description="Arm the controller and stay attached, streaming a status line, until Ctrl-C "
                                   "or --duration; the board is disarmed on exit. rodctl must stay running while "
                                   "the rod is armed: the firmware disarms itself (FAULT, heartbeat lost) 0.5 s "
                                   "after the host falls silent.")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--swing-up", action="store_true", help="swing up from hanging, then balance")
    g.add_argument("--balance", action="store_true", help="catch near upright, then balance")
    add_port_arg(p)
    p.add_argument("--duration", type=float, metavar="S", help="disarm and leave after S seconds")
    p.add_argument("--out", metavar="PATH", help="also log every frame to PATH (as rodctl log)")
    p.add_argument("--format", choices=("csv", "parquet"), help="log format (default from --out's extension)")
    add_design_args(p)
    p.set_defaults(func=run_arm)

    p = sub.add_parser("disarm", help="turn the motor driver off (DISARMED, reason HOST)")
    add_port_arg(p)
    p.set_defaults(func=run_disarm)

    p = sub.add_parser("clear-fault", help="leave FAULT for DISARMED")
    add_port_arg(p)
    p.set_defaults(func=run_clear_fault)

    names = ", ".join(f"{s.name} [{s.unit or 'integer'}]" for s in SETTINGS.values())
    p = sub.add_parser("set", help="change run-time settings (swing amplitude/angle, catch angle, ...)",
                       description=f"Change run-time settings on the board until it resets. Names: {names}. "
                                   "The board checks the bounds; a refused value is reported with its range.")
    p.add_argument("assignments", nargs="+", metavar="NAME=VALUE")
    add_port_arg(p)
    add_design_args(p)
    p.set_defaults(func=run_set)

    p = sub.add_parser("console", help="interactive prompt: arm, disarm, clear, set, status, quit",
                       description="Interactive session with a live status line; the heartbeat runs while it is "
                                   "open and the board is disarmed when it closes.\n\n" + CONSOLE_HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    add_port_arg(p)
    add_design_args(p)
    p.set_defaults(func=run_console)

    p = sub.add_parser("sim-device", help="run the virtual board on a pseudo-terminal for any serial tool",
                       description="Run the firmware's host build against the simulated rod in real time on a "
                                   "pseudo-terminal; prints the /dev/pts path as its last line and runs until "
                                   "Ctrl-C. Any tool, including another rodctl (--port PATH), can then talk to a "
                                   "virtual board over a real serial device. Mode changes are reported on stderr.")
    p.add_argument("--pty", action="store_true", default=True, help="serve on a pseudo-terminal (the default)")
    p.add_argument("--params", metavar="FILE", help="parameter file for the firmware build and the plant")
    p.add_argument("--plant", choices=("inextensible", "der"), default="inextensible", help="simulated rod model")
    p.add_argument("--edges", type=int, help="plant edges (default: the parameters' N)")
    p.add_argument("--link", metavar="PATH", help="also make PATH a symlink to the pseudo-terminal")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.set_defaults(func=run_sim_device)

    p = sub.add_parser("log-convert", help="convert a CSV log or a Parquet journal left by a kill to Parquet")
    p.add_argument("journal", metavar="CSV")
    p.add_argument("--out", metavar="PATH", help="Parquet file (default: the journal's name without .journal.csv)")
    p.set_defaults(func=run_log_convert)
