"""rodctl log and rodctl arm: stay attached to the board, optionally armed, optionally logging."""

from __future__ import annotations

import sys

from rodgains.errors import UserError

from rodctl.cli.common import (ARM_CHOICES, RateMeter, StatusLine, add_design_args, add_port_arg, check_duration,
                               ctrl_c_watch, no_interrupts, session_for, status_text, stop_signals)
from rodctl.link import protocol as P
from rodctl.link.attach import Attached, attach
from rodctl.link.session import Session, fault_text, name_of
from rodctl.logs.writer import default_log_name


def stream(args, arm_mode=None, out: str | None = None, what: str = "log") -> int:
    """Stay attached: optional arm, optional log, a status line, until Ctrl-C / --duration / error."""
    from rodctl.logs.writer import check_new, log_format, require_format

    ctrl_c_seen = ctrl_c_watch()
    duration = getattr(args, "duration", None)
    check_duration(duration)
    fmt = None
    if out is not None:
        from rodctl.cli.outputs import check_name

        check_name(out, "--out")  # an empty name (an unset shell variable) is not the current folder
        fmt = log_format(out, getattr(args, "format", None))
        require_format(fmt)  # before touching the board
        check_new(out, fmt, getattr(args, "force", False))
        from rodctl.cli.outputs import check_output

        check_output(out, "--out", make_parent=True)  # the folder can be written, before the board is touched
    session = session_for(args)
    status = StatusLine()
    meter = RateMeter()

    def started(a: Attached) -> None:
        nonlocal meter
        meter = RateMeter(a.session.frames)
        h = a.session.hello
        design = (f"parameters {a.source}" if a.params is not None
                  else f"parameters unknown (header {bytes(h.header_sha256).hex()[:16]})")
        target = f" -> {a.writer.path}" if a.writer else ""
        if a.mismatch:
            print(f"rodctl: warning: {a.mismatch}", file=sys.stderr, flush=True)
        print(f"{what}: {a.session.port}{target}  (firmware {h.fw_major}.{h.fw_minor}.{h.fw_patch}, N={h.n}, "
              f"{1e6 / h.period_us:g} Hz, {design}); Ctrl-C stops" + (" and disarms" if arm_mode else ""),
              file=sys.stderr, flush=True)

    def armed(ack) -> None:
        print(f"armed {arm_mode.name.lower().replace('_', '-')}: mode {name_of(P.Mode, ack.mode)}",
              file=sys.stderr, flush=True)

    def tick(a: Attached) -> None:
        if status.due():
            status.update(status_text(a.session, meter.rate(a.session.frames), a.writer.rows if a.writer else None))

    with stop_signals():
        a = attach(session, args, out=out, fmt=fmt, overwrite=getattr(args, "force", False),
                   arm_mode=arm_mode, duration_s=duration, interrupted=ctrl_c_seen, shield=no_interrupts,
                   started=started, armed=armed, tick=tick, stopping=status.end)
    writer, c, ended = a.writer, a.counters, a.ended
    if writer is not None and writer.failure is not None:  # the log stopped where the system refused a write
        raise UserError(writer.failure_text() + _disarm_note(session))
    if writer is not None:
        print(f"wrote {writer.path}: {writer.rows} telemetry rows, {writer.events} events ({c['frames']} frames); "
              f"seq gaps {c['seq_gaps']}, CRC errors {c['crc_errors']}, device dropped {c['device_dropped']}"
              + _disarm_note(session),
              file=sys.stderr, flush=True)
    elif session.hello is not None and ended != "error":
        print(f"{what} ended ({ended}): {c['frames']} frames, seq gaps {c['seq_gaps']}, "
              f"CRC errors {c['crc_errors']}" + _disarm_note(session),
              file=sys.stderr, flush=True)
    if a.error is not None:
        raise a.error
    if a.fault is not None:  # the run the board was armed for ended there: a failure on its own terms
        raise UserError(f"the board tripped {a.fault_after_s:.3f} s after arming: {fault_text(a.fault.reason)}; "
                        "the driver is off" + (f"; {writer.path} keeps the run up to the trip" if writer else ""))
    if a.interrupted and session.hello is None:  # nothing armed or written yet
        print("rodctl: interrupted before the board answered; nothing was armed or written", file=sys.stderr,
              flush=True)
        return 130
    return 0


def _disarm_note(session: Session) -> str:
    t = session.telemetry
    if t is not None and t.mode == P.Mode.FAULT:  # a DISARM leaves FAULT as it is: the driver is off either way
        return "; the board is in FAULT, its driver off"
    if session.disarm_acked:
        return "; disarmed"
    if session.disconnected is not None:
        return "; link lost, not disarmed (the board's watchdog disarms it)"
    return "; disarm not confirmed (the board's watchdog disarms it)"


def run_log(args) -> int:
    fmt = args.format
    out = args.out if args.out is not None else default_log_name(fmt or "csv")
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
