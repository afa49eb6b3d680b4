"""What every device command shares: --port/--params/--set, opening a session, the status line, signals."""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import threading
import time
import urllib.parse as urlparse
from pathlib import Path

from rodgains.errors import InputError

from rodctl.link import protocol as P
from rodctl.link.attach import Stopped
from rodctl.link.session import Session, is_tty, mode_text
from rodctl.logs.schema import from_upright_deg


PORT_HELP = ("serial port (e.g. /dev/ttyACM0), any pyserial URL, or sim:// for the simulated rod "
             "(sim://?plant=der&edges=20&params=FILE); default: the one Teensy on USB (16C0:0483)")


ARM_CHOICES = {"swing-up": P.ArmMode.SWING_UP, "balance": P.ArmMode.BALANCE}


def add_port_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--port", metavar="PORT", help=PORT_HELP)


def add_design_args(p: argparse.ArgumentParser, params_help: str | None = None) -> None:
    p.add_argument("--params", metavar="FILE",
                   help=params_help or "parameter file the firmware may have been built from (identifies the design by "
                        "its hash); with --port sim:// it also builds the virtual board's firmware and plant")
    p.add_argument("--set", metavar="SECTION.KEY=VALUE", action="append", default=[], dest="overrides",
                   help="override one parameter of --params (repeatable)")


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


MAX_WALL_DURATION_S = 7 * 86400.0


# A simulated run's length [s] (`sim --duration`, `robustness` / `sweep` / `tune --seconds`). Shorter runs hold
# fewer than 5 periods of the slowest loop (loop.rate_hz >= 100 Hz): below one period the run has no samples at
# all, and the metrics need two.
MIN_SIM_SECONDS = 0.05
MAX_SIM_SECONDS = 600.0


def check_sim_seconds(seconds: float | None, flag: str) -> None:
    """A simulated run's length [s], None for the default; out of [MIN_SIM_SECONDS, MAX_SIM_SECONDS]: InputError."""
    if seconds is not None and not MIN_SIM_SECONDS <= seconds <= MAX_SIM_SECONDS:
        raise InputError(f"{flag} {seconds:g}: must be in [{MIN_SIM_SECONDS:g}, {MAX_SIM_SECONDS:g}] s")


def check_duration(seconds: float | None) -> None:
    """--duration [s] of wall time: None runs until stopped; anything else must be in (0, a week]
    (InputError, exit 2): inf or 1e300 would only be "until stopped" spelt as a number."""
    if seconds is not None and not 0 < seconds <= MAX_WALL_DURATION_S:
        raise InputError(f"--duration {seconds:g}: must be in (0, {MAX_WALL_DURATION_S:g}] s; leave it out to run "
                         "until stopped")


def status_text(s: Session, fps: float, rows: int | None = None) -> str:
    c = s.counters()
    t = s.telemetry
    parts = [f"{s.elapsed():6.1f} s", f"{fps:6.0f} frames/s", f"CRC errors {c['crc_errors']}",
             f"seq gaps {c['seq_gaps']}", f"device dropped {c['device_dropped']}"]
    if t is not None:
        parts.append(f"mode {mode_text(t.mode, t.reason)}")
        if t.n:
            parts.append(f"theta1 {from_upright_deg(t.theta_hat[0]):+7.1f} deg from upright")
    if rows is not None:
        parts.append(f"{rows} rows")
    return " | ".join(parts)


@contextlib.contextmanager
def stop_signals():
    """SIGTERM and SIGHUP stop like Ctrl-C (a KeyboardInterrupt in the main thread, `Stopped` to say which),
    unless they are ignored (nohup ignores SIGHUP)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def raise_interrupt(signum, frame):
        raise Stopped(signal.Signals(signum).name)

    old = {}
    for sig in (signal.SIGTERM, getattr(signal, "SIGHUP", None)):
        # one ignored on purpose stays ignored: `nohup rodctl log ...` outlives the terminal it came from
        if sig is not None and signal.getsignal(sig) is not signal.SIG_IGN:
            old[sig] = signal.signal(sig, raise_interrupt)
    try:
        yield
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)


def ctrl_c_watch():
    """A test that says whether a Ctrl-C came since this call. main() counts every SIGINT, so one that a
    library swallowed (a bare `except:` around an import) still keeps a command from arming."""
    from rodctl.cli import interrupts

    start = interrupts()
    return lambda: interrupts() != start


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


def device_port(args) -> str | None:
    """--port, with --params/--set passed on to a sim:// board (its firmware build and its plant)."""
    port = getattr(args, "port", None)
    params = getattr(args, "params", None)
    overrides = list(getattr(args, "overrides", None) or [])
    if not port or not port.startswith("sim://") or not (params or overrides):
        return port
    from rodgains.params import load_params

    load_params(params, overrides)  # a bad file or --set is one clear line before the board starts
    parts = urlparse.urlsplit(port)
    query = urlparse.parse_qsl(parts.query, keep_blank_values=True)
    if params and not any(k == "params" for k, _ in query):
        query.append(("params", str(Path(params).resolve())))
    query += [("set", o) for o in overrides]
    return "sim://?" + urlparse.urlencode(query)


# A command's session heartbeats only while its main thread looked at the link this recently [s]: longer than
# any pause of a healthy command (a Parquet row group written on a slow card, a window's redraw), short enough
# that a stuck one leaves the board to disarm itself within 1.5 s (with its 0.5 s heartbeat timeout)
LIVENESS_S = 1.0


def session_for(args, **kw) -> Session:
    """A Session on the command's port (not yet open; use it as a context manager). Its heartbeats stop when the
    command's main thread has not checked the link for LIVENESS_S (Session liveness_s): a command stuck on a
    paused terminal or a hung window leaves the board to disarm itself."""
    kw.setdefault("liveness_s", LIVENESS_S)
    return Session(device_port(args), **kw)
