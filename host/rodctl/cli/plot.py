"""rodctl plot: a log's figure (rodctl.logs.plots), in a window or a PNG; --live opens the scope.

Reads only the columns the figure needs (rodctl.logs.plots.PLOT_COLUMNS), from CSV, Parquet or MCAP.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from rodgains.errors import InputError

from rodctl.logs.plots import PANELS, PLOT_COLUMNS, make_figure, save_figure

NON_INTERACTIVE = {"agg", "pdf", "ps", "svg", "pgf", "cairo", "template", "module://matplotlib_inline.backend_inline"}


def display_problem() -> str | None:
    """Why no window can be opened here, or None when one can."""
    if sys.platform.startswith("linux") or "bsd" in sys.platform:
        if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
            return "no display (DISPLAY is not set)"
    env = os.environ.get("MPLBACKEND", "").lower()
    if env in NON_INTERACTIVE:
        return f"MPLBACKEND={env} cannot open windows"
    import matplotlib

    backend = matplotlib.get_backend().lower()
    if backend in NON_INTERACTIVE:
        return f"the matplotlib backend is {backend}, which cannot open windows"
    return None


def default_figure(log: str) -> str:
    """Where a log's figure goes without --out and without a display: LOG.png."""
    return str(Path(log).with_suffix("")) + ".png"


def run_plot(args) -> int:
    if args.live:
        if args.log:
            raise InputError(f"--live opens the scope of a board, not a log: drop {args.log} or --live")
        from rodctl.cli.scope import run_scope

        return run_scope(args)
    if not args.log:
        raise InputError("name a log to plot (rodctl plot run.csv), or --live --port PORT")
    scope_only = [f"--{k.replace('_', '-')}" for k in ("port", "arm", "duration", "record", "format", "screenshot",
                                                          "window", "params")
                  if getattr(args, k, None) is not None] + (["--set"] if getattr(args, "overrides", None) else [])
    if scope_only:  # they were dropped without a word: a log's figure has no board to arm or time to wait
        raise InputError(f"{', '.join(scope_only)}: only with --live (the scope of a board), not for a log's figure")
    from rodctl.cli.outputs import check_output
    from rodctl.logs.reader import read_log

    if not 1 <= args.snapshots <= 100:
        raise InputError(f"--snapshots {args.snapshots}: must be in 1 .. 100")
    if args.out is not None:  # a single named result: its folder must exist, so a typo is caught
        check_output(args.out, "--out", figure=True, force=args.force)
    elif display_problem() is not None:  # LOG.png beside the log: checked before reading it
        check_output(default_figure(args.log), "figure (no --out, no display)", figure=True)
    from rodctl.logs.reader import cut_short, reading_note

    note = reading_note(args.log)  # seconds of silence else
    if note:
        print(f"{note} ...", file=sys.stderr, flush=True)
    log = read_log(args.log, columns=PLOT_COLUMNS)
    meta, data = log
    short = cut_short(log)
    if short:
        print(f"warning: {short}", file=sys.stderr)
    out = args.out
    if out is None and display_problem() is None:
        import matplotlib.pyplot as plt

        fig = plt.figure(figsize=(14, 9), layout="constrained")
        make_figure(meta, data, snapshots=args.snapshots, fig=fig)
        plt.show()
        return 0
    fig = make_figure(meta, data, snapshots=args.snapshots)
    if out is None:
        out = default_figure(args.log)
        print(f"no display: writing {out}", file=sys.stderr)
    path = save_figure(fig, out)
    print(f"wrote {path}: {len(data)} telemetry frames, panels: {', '.join(PANELS)}")
    return 0


def register(sub) -> None:
    p = sub.add_parser("plot", help="plot a log (time series, rod shapes, edge angles) or open the live scope",
                       description="Plot a rodctl log (CSV, Parquet or MCAP): every angle estimate, torque, duty and "
                                   "mode vs time, rod shapes at events (start, catch, the estimate settled within 2 deg, fault, end; paper "
                                   "Fig. 5) and every edge angle from the nearest upright (Fig. 6). --out writes a "
                                   "PNG (Agg, works headless; an existing one is kept unless --force); without --out a "
                                   "window opens, or LOG.png is written (replaced) when there is no display. --live is "
                                   "`rodctl scope`.")
    p.add_argument("log", nargs="?", metavar="LOG", help="a log written by rodctl log or rodctl sim")
    p.add_argument("--out", metavar="PNG", help="write the figure to this file")
    p.add_argument("--snapshots", type=int, default=6, metavar="K", help="at most K rod shapes, at events (default 6)")
    p.add_argument("--live", action="store_true", help="the live scope of a board (--port): same as rodctl scope")
    from rodctl.cli.scope import add_scope_args

    add_scope_args(p)
    p.set_defaults(func=run_plot)
