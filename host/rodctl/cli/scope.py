"""rodctl scope: one live session with a board: rod shape, time series, arm/disarm/set/record.

The window shows the estimated rod (red, node 0 on the motor axis), every edge angle from the
nearest upright [deg], torque and duty, and the mode over the last --window seconds. Keys (and the
buttons under the plots):
    s  arm swing-up          b  arm balance        d or space  disarm     c  clear fault
    r  start/stop recording (rod-YYYYmmdd-HHMMSS.csv, or --record PATH)    q  quit
    the "set" box takes NAME=VALUE ... (as `rodctl set`)
The session's heartbeat runs the whole time. Closing the window, q, Ctrl-C or SIGTERM disarm the
board and end the session without a traceback.
"""

from __future__ import annotations

import shlex
import signal
import sys
import threading

from rodgains.errors import InputError, UserError

WINDOW_S = 10.0  # seconds of time series shown by default [s]


def add_scope_args(p) -> None:
    from rodctl.cli.common import add_design_args, add_port_arg
    from rodctl.logs.writer import FORMATS

    add_port_arg(p)
    p.add_argument("--window", type=float, metavar="S", help="seconds of time series shown (default 10)")
    p.add_argument("--duration", type=float, metavar="S", help="close (and disarm) after S seconds")
    p.add_argument("--arm", choices=("swing-up", "balance"), help="arm right after connecting")
    p.add_argument("--record", metavar="PATH", help="record from the start to PATH (r toggles recording)")
    p.add_argument("--format", choices=FORMATS, help="recording format (default: from the extension, else csv)")
    p.add_argument("--force", action="store_true", help="replace an existing recording file or --screenshot (rodctl plot: --out)")
    p.add_argument("--screenshot", metavar="PNG",
                   help="when the scope ends (--duration, q, Ctrl-C), save the window as it last looked to this PNG "
                        "(its folder must exist)")
    add_design_args(p)


def check_scope_args(args) -> None:
    """Every option the scope takes, before the board is touched (InputError: one line, exit 2)."""
    import math

    from rodctl.cli.common import check_duration
    from rodctl.cli.outputs import check_name, check_output

    check_duration(args.duration)
    if args.window is None:
        args.window = WINDOW_S
    if not (math.isfinite(args.window) and 0 < args.window <= 3600):
        raise InputError(f"--window {args.window:g}: must be in (0, 3600] s")
    if args.screenshot is not None:
        check_output(args.screenshot, "--screenshot", force=bool(args.force), figure=True)
    if args.record is not None:
        from rodctl.logs.writer import check_new, log_format

        check_name(args.record, "--record")  # an empty name is not the current folder
        check_new(args.record, log_format(args.record, args.format), args.force)
        check_output(args.record, "--record", make_parent=True)
    if getattr(args, "params", None) or getattr(args, "overrides", None):
        from rodgains.params import load_params

        load_params(args.params, args.overrides)  # a bad file is named now, not after the display and the board


def log_instead(args, out: str) -> str:
    """The `rodctl log` that records what this scope would have shown: its port, arming, duration, design."""
    g = {k: getattr(args, k, None) for k in ("port", "arm", "duration", "format", "force")}
    parts = ["rodctl", "log", "--port", g["port"] or "PORT"]
    if g["arm"]:
        parts += ["--arm", g["arm"]]
    if g["duration"] is not None:
        parts += ["--duration", f"{g['duration']:g}"]
    from rodctl.link.design import design_flags

    parts += ["--out", out] + (["--format", g["format"]] if g["format"] else []) + (["--force"] if g["force"] else [])
    parts += design_flags(args)
    return " ".join(p if p == "PORT" else shlex.quote(p) for p in parts)


def run_scope(args) -> int:
    from rodctl.cli.plot import default_figure, display_problem

    from rodctl.cli.common import ctrl_c_watch, session_for

    ctrl_c_seen = ctrl_c_watch()
    check_scope_args(args)
    why = display_problem()
    if why is not None:
        out = getattr(args, "record", None) or f"run.{getattr(args, 'format', None) or 'csv'}"
        raise UserError(f"the scope needs a display: {why}. Record instead with `{log_instead(args, out)}`, then "
                        f"`rodctl plot {shlex.quote(out)} --out {shlex.quote(default_figure(out))}`")
    from rodctl.scope import display_guard
    from rodctl.scope.loop import close_scope, end_on_lost_display, open_scope, run_window, shot_saved

    stop = threading.Event()
    old = {}
    failures: list[BaseException] = []  # what went wrong in the window's callbacks or while ending

    def request_stop(signum, frame):
        stop.set()

    def say(message: str) -> None:
        print(f"scope: {message}", file=sys.stderr, flush=True)

    with session_for(args) as s:
        for sig in (signal.SIGINT, signal.SIGTERM):
            old[sig] = signal.signal(sig, request_stop)
        scope = None

        def display_lost(why: str) -> None:  # Xlib ends the process after this: no finally below runs
            print(f"rodctl: {why}: {end_on_lost_display(s, scope)}", file=sys.stderr, flush=True)

        try:
            display_guard.install(display_lost)
            scope = open_scope(s, args, say=say)
            if args.record:
                scope.toggle_recording()
            if ctrl_c_seen():  # a Ctrl-C that something swallowed: end, never arm
                stop.set()
            h = s.hello
            run_window(scope, stop, duration_s=args.duration, screenshot=args.screenshot, failures=failures,
                       arm=args.arm if not stop.is_set() else None,
                       ready=lambda: say(f"{s.port} (firmware {h.fw_major}.{h.fw_minor}.{h.fw_patch}, N={h.n}); keys: "
                                         "s swing-up, b balance, d disarm, c clear fault, r record, q quit; closing the "
                                         "window disarms"))
        finally:
            for sig, hnd in old.items():
                signal.signal(sig, hnd)
            close_scope(scope, failures)
    rec = f"; recorded {', '.join(scope.recorded)}" if scope is not None and scope.recorded else ""
    if getattr(args, "screenshot", None) and shot_saved(args.screenshot, failures):
        rec += f"; screenshot {args.screenshot}"
    print(f"scope ended: {'disarmed' if s.disarm_acked else 'disarm not confirmed (the watchdog disarms)'}{rec}",
          file=sys.stderr, flush=True)
    if failures:
        raise failures[0]
    return 0


def register(sub) -> None:
    p = sub.add_parser("scope", help="live window: rod shape and time series; arm, disarm, set, record",
                       description=__doc__.split("\n\n", 1)[1], formatter_class=__import__("argparse")
                       .RawDescriptionHelpFormatter)
    add_scope_args(p)
    p.set_defaults(func=run_scope)
