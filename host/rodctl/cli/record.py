"""rodctl log and rodctl arm: stay attached to the board, optionally armed, optionally logging."""

from __future__ import annotations

import sys
import time

from rodgains.errors import UserError

from rodctl.cli.common import (ARM_CHOICES, RateMeter, StatusLine, add_design_args, add_port_arg, check_duration,
                               ctrl_c_watch, no_interrupts, session_for, status_text, stop_signals)
from rodctl.link import protocol as P
from rodctl.link.design import design_params
from rodctl.link.session import Session, name_of
from rodctl.logs.writer import default_log_name


def stream(args, arm_mode=None, out: str | None = None, what: str = "log") -> int:
    """Stay attached: optional arm, optional log, a status line, until Ctrl-C / --duration / error."""
    from rodctl.logs.metadata import device_metadata
    from rodctl.logs.writer import LogWriter, check_new, log_format, require_format

    ctrl_c_seen = ctrl_c_watch()
    duration = getattr(args, "duration", None)
    check_duration(duration)
    fmt = None
    if out is not None:
        fmt = log_format(out, getattr(args, "format", None))
        require_format(fmt)  # before touching the board
        check_new(out, fmt, getattr(args, "force", False))
        from rodctl.cli.outputs import check_output

        check_output(out, "--out", make_parent=True)  # the folder can be written, before the board is touched
    session = session_for(args)
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
                writer = LogWriter(out, meta, n=h.n, fmt=fmt, overwrite=getattr(args, "force", False))
                session.add_listener(writer, replay=True)
            design = (f"parameters {source}" if params is not None
                      else f"parameters unknown (header {bytes(h.header_sha256).hex()[:16]})")
            target = f" -> {writer.path}" if writer else ""
            print(f"{what}: {session.port}{target}  (firmware {h.fw_major}.{h.fw_minor}.{h.fw_patch}, N={h.n}, "
                  f"{1e6 / h.period_us:g} Hz, {design}); Ctrl-C stops" + (" and disarms" if arm_mode else ""),
                  file=sys.stderr, flush=True)
            if arm_mode is not None:
                if ctrl_c_seen():  # a Ctrl-C that something swallowed: never arm after it
                    raise KeyboardInterrupt
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
                    try:
                        writer.close(session.log_trailer(ended))
                    except UserError as e:
                        error = error or e
                    except OSError as e:
                        error = error or UserError(f"closing {writer.path} failed: {e}")
    if writer is not None:
        print(f"wrote {writer.path}: {writer.rows} telemetry rows, {writer.events} events ({c['frames']} frames); "
              f"seq gaps {c['seq_gaps']}, CRC errors {c['crc_errors']}, device dropped {c['device_dropped']}"
              + _disarm_note(session),
              file=sys.stderr, flush=True)
    elif session.hello is not None and ended != "error":
        print(f"{what} ended ({ended}): {c['frames']} frames, seq gaps {c['seq_gaps']}, "
              f"CRC errors {c['crc_errors']}" + _disarm_note(session),
              file=sys.stderr, flush=True)
    if error is not None:
        raise error
    if ended == "Ctrl-C" and session.hello is None:  # before the board answered: nothing armed, nothing written
        print("rodctl: interrupted before the board answered; nothing was armed or written", file=sys.stderr,
              flush=True)
        return 130
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


def register(sub) -> None:
    p = sub.add_parser("log", help="record every frame to CSV, Parquet or MCAP with a live status line",
                       description="Record every frame the board sends until Ctrl-C or --duration, with a live "
                                   "status line on stderr: one row per telemetry frame; HELLO, ACKs and mode "
                                   "changes as events (docs/host.md, Logs). A CSV log is written as frames arrive "
                                   "(4x per second) and stays readable if the process is killed. An existing log "
                                   "is refused unless --force. On exit the board is disarmed.")
    add_port_arg(p)
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.add_argument("--out", metavar="PATH", help="log file (default rod-YYYYmmdd-HHMMSS.csv)")
    p.add_argument("--format", choices=("csv", "parquet", "mcap"),
                   help="file format (default: from --out's extension, else csv); see docs/host.md, Logs")
    p.add_argument("--force", action="store_true", help="replace an existing log")
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
    p.add_argument("--format", choices=("csv", "parquet", "mcap"), help="log format (default from --out's extension)")
    p.add_argument("--force", action="store_true", help="replace an existing log")
    add_design_args(p)
    p.set_defaults(func=run_arm)
