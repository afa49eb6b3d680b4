"""Staying attached to a board (rodctl log, rodctl arm): open the session, log every frame if asked, arm if asked,
wait until Ctrl-C, a duration or an error; then disarm, close the log with the link's trailer, count what came.

    a = attach(session, args, out="run.csv", fmt="csv", arm_mode=P.ArmMode.BALANCE, duration_s=10.0,
               started=say_start, armed=say_armed, tick=show_status, stopping=end_status)
    a.ended, a.counters, a.writer     # "end" | "duration" | "FAULT" | "Ctrl-C" | "SIGTERM" | "SIGHUP" | "error"; the
                                      # link's counters; the log
    if a.error is not None:           # kept, not raised: the caller says what was written first
        raise a.error

Nothing here prints: what the terminal shows goes through the callbacks. Signals are the caller's: a
KeyboardInterrupt ends the attach as "Ctrl-C" (a `Stopped` one under its signal's name), and `shield` may hold
further ones off while the board is disarmed and the log closed.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable, ContextManager

from rodgains.errors import UserError

from rodctl.link import protocol as P
from rodctl.link.design import design_mismatch, design_params
from rodctl.link.session import Session, fault_text

if TYPE_CHECKING:
    from rodgains.params import Params

    from rodctl.logs.writer import LogWriter


class Stopped(KeyboardInterrupt):
    """SIGTERM or SIGHUP, stopping a command as Ctrl-C does (the board disarmed, the log closed), but logged and
    said under the signal's own name: a log ended by a service manager or `timeout` is not a user's Ctrl-C."""

    def __init__(self, signal_name: str):
        super().__init__(signal_name)
        self.signal_name = signal_name


def stopped_by(e: KeyboardInterrupt) -> str:
    """How an interrupt ended a command, as a log's trailer records it: "Ctrl-C", or the stop signal's name."""
    return e.signal_name if isinstance(e, Stopped) else "Ctrl-C"


POLL_S = 0.05  # how often the link, the log and the status are looked at while attached [s]


@dataclass
class Attached:
    """One attach: its session, its log (None: not logging) and the design the board runs (design_params);
    once attach() returns, how it ended, the link's counters after the close and the error that ended it."""

    session: Session
    writer: LogWriter | None = None
    params: Params | None = None
    source: str = "unknown"
    ended: str = "end"
    counters: dict[str, int] = field(default_factory=dict)
    error: BaseException | None = None
    mismatch: str | None = None  # --params / --set named a design the board does not run (design_mismatch)
    fault: object | None = None  # the first FAULT telemetry of an armed run (it ends the attach: ended "FAULT")
    fault_after_s: float = 0.0  # the board's time from the ARM to the first FAULT frame seen (to a frame) [s]

    @property
    def interrupted(self) -> bool:
        """Ended by Ctrl-C or a stop signal (`stopped_by`'s names), not by its end, its duration, a FAULT or an
        error."""
        return self.ended not in ("end", "duration", "FAULT", "error")


def _nothing(*_args) -> None:
    pass


def attach(session: Session, design_args=None, *, out: str | None = None, fmt: str | None = None,
           overwrite: bool = False, arm_mode: P.ArmMode | None = None, duration_s: float | None = None,
           interrupted: Callable[[], bool] = lambda: False,
           shield: Callable[[], ContextManager] = contextlib.nullcontext,
           started: Callable[[Attached], None] = _nothing, armed: Callable[[object], None] = _nothing,
           tick: Callable[[Attached], None] = _nothing, stopping: Callable[[], None] = _nothing) -> Attached:
    """Open `session` (not yet open), log every frame to `out` (fmt, overwrite: as LogWriter) from the first one
    on, arm `arm_mode`, and stay until duration_s [s] has passed (None: until Ctrl-C or an error), or, armed,
    until the board trips a FAULT: an armed run ends there (a.fault), as nothing it was armed for goes on.

    design_args: --params/--set, to name the design the board runs (design_params). started(a) is called once
    the session is open and the log begun; armed(ack) with the board's ACK of the ARM; tick(a) every POLL_S
    while attached; stopping() when it ends, inside `shield()`, once the board is disarmed.
    interrupted() says whether a Ctrl-C came that something swallowed: then the board is never armed.
    """
    from rodctl.logs.writer import attach_device_log

    a = Attached(session, ended="duration" if duration_s is not None else "end")
    try:
        session.open()
        a.params, a.source = design_params(session, design_args)
        a.mismatch = design_mismatch(session, design_args, a.source)
        latest = session.telemetry if session.telemetry is not None else session.hello
        if arm_mode is not None and latest is not None and latest.mode == P.Mode.FAULT:
            # the ARM would be refused: no log of a run that never started, and an old one --force named is kept
            raise UserError(f"{fault_text(latest.reason)}; nothing was armed" + (f" or written to {out}" if out else ""))
        if out is not None:
            a.writer = attach_device_log(session, out, params=a.params, params_source=a.source, fmt=fmt,
                                         overwrite=overwrite, replay=True)
        started(a)
        if arm_mode is not None:
            if interrupted():
                raise KeyboardInterrupt
            clock: dict = {}  # the board's clock [us] at the ARM's ACK and the first FAULT frame after it

            def stamp(f, _t) -> None:
                if f.type == P.MsgType.ACK and f.msg.command == P.MsgType.ARM and f.msg.result == P.AckResult.OK:
                    clock["arm"] = f.time_us
                elif f.type == P.MsgType.TELEMETRY and f.msg.mode == P.Mode.FAULT and "arm" in clock:
                    clock.setdefault("fault", f.time_us)
            session.add_listener(stamp, replay=False)
            armed(session.arm(arm_mode))
            armed_at, armed_seen = time.monotonic(), session.telemetry_seen
        t_end = None if duration_s is None else time.monotonic() + duration_s
        while t_end is None or time.monotonic() < t_end:
            time.sleep(POLL_S)
            session.check()
            if a.writer is not None:
                a.writer.maybe_flush()  # LogWriteFailed too when the receiving thread's write was refused
            if session.listener_error is not None:
                e = session.listener_error
                raise e if isinstance(e, UserError) else UserError(f"writing {out} failed: {e}")
            tick(a)
            t = session.telemetry
            if arm_mode is not None and session.telemetry_seen > armed_seen and t is not None and t.mode == P.Mode.FAULT:
                a.ended, a.fault = "FAULT", t
                # the board's clock: the host's sees the frames in USB batches, at its own 50 ms polls
                a.fault_after_s = (((clock["fault"] - clock["arm"]) & 0xFFFFFFFF) * 1e-6 if "fault" in clock
                                   else time.monotonic() - armed_at)
                break
    except KeyboardInterrupt as e:
        a.ended = stopped_by(e)
    except BaseException as e:  # noqa: BLE001 - the log closed first, then the error
        a.ended = "error"
        a.error = e
    finally:
        with shield():
            # DISARM first: stopping() writes to the terminal, which may block (paused with Ctrl-S)
            session.close()  # DISARM when possible; every frame received is in the writer now
            stopping()
            a.counters = session.counters()
            if a.writer is not None:
                session.remove_listener(a.writer)
                try:
                    a.writer.close(session.log_trailer(a.ended))
                except UserError as e:
                    a.error = a.error or e
    return a
