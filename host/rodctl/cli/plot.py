"""rodctl plot: time series, rod shapes (paper Fig. 5) and edge angles (Fig. 6) from a log; a live view.

    fig = make_figure(*read_log("run.csv"))    # matplotlib Figure, no backend needed
    save_figure(fig, "run.png")                # Agg

Panels (PANELS, in this order): every angle estimate theta_hat_i [rad] vs time; torque [N m];
duty; mode; rod shapes at several times (nodes from the theta-hat: x_k = sum l sin theta_j,
y_k = -sum l cos theta_j, l = rod length / N from the log's parameters); every edge angle in
degrees from the downward vertical (0 hanging, 180 upright) vs time.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from rodgains.errors import UserError

from rodctl.link import protocol as P

PANELS = ("angle estimates", "torque", "duty", "mode", "rod shapes (Fig. 5)", "edge angles (Fig. 6)")
MODE_NAMES = [m.name for m in sorted(P.Mode, key=int)]
NON_INTERACTIVE = {"agg", "pdf", "ps", "svg", "pgf", "cairo", "template", "module://matplotlib_inline.backend_inline"}


def edge_length(meta: dict, n: int) -> tuple[float, str]:
    """(l, note): rod length / N from the log's parameters (default rod when the log has none)."""
    from rodctl.logs.logfile import params_of

    p = params_of(meta)
    if p is not None:
        return p["rod"]["length"] / n, ""
    from rodgains.params import load_params

    return load_params()["rod"]["length"] / n, " (parameters unknown: default rod length assumed)"


def shape_nodes(theta: np.ndarray, l: float) -> tuple[np.ndarray, np.ndarray]:
    """Node coordinates (N+1 each, node 0 on the axis) of one rod shape from its edge angles."""
    th = np.asarray(theta, float)
    x = np.concatenate([[0.0], np.cumsum(l * np.sin(th))])
    y = np.concatenate([[0.0], -np.cumsum(l * np.cos(th))])
    return x, y


def snapshot_indices(count: int, k: int) -> list[int]:
    if count == 0:
        return []
    k = max(1, min(k, count))
    return sorted(set(int(round(i)) for i in np.linspace(0, count - 1, k)))


def make_figure(meta: dict, data: np.ndarray, snapshots: int = 6, title: str | None = None, fig=None):
    """The log's Figure (matplotlib.figure.Figure, 6 axes: see PANELS); draws into `fig` when given."""
    from matplotlib.figure import Figure

    from rodctl.logs.logfile import device_time_s, n_edges, telemetry, theta_hat

    tl = telemetry(data)
    n = n_edges(data)
    if len(tl) == 0:
        raise UserError("the log has no telemetry rows to plot")
    t = device_time_s(tl)
    th = theta_hat(tl)
    l, note = edge_length(meta, n)

    if fig is None:
        fig = Figure(figsize=(14, 9), layout="constrained")
    gs = fig.add_gridspec(4, 2, width_ratios=(1.6, 1))
    ax_th = fig.add_subplot(gs[0, 0])
    ax_tq = fig.add_subplot(gs[1, 0], sharex=ax_th)
    ax_du = fig.add_subplot(gs[2, 0], sharex=ax_th)
    ax_mo = fig.add_subplot(gs[3, 0], sharex=ax_th)
    ax_sh = fig.add_subplot(gs[0:2, 1])
    ax_f6 = fig.add_subplot(gs[2:4, 1], sharex=ax_th)

    for i in range(n):
        ax_th.plot(t, th[:, i], lw=0.8, label=f"theta_hat_{i + 1}")
    ax_th.axhline(math.pi, color="0.6", ls="--", lw=0.6)
    ax_th.set_ylabel("angle estimate [rad]")
    ax_th.set_title("angle estimates (pi = upright)")
    if n <= 10:
        ax_th.legend(fontsize=7, ncol=min(n, 5), loc="best")

    ax_tq.plot(t, tl["torque_Nm"], lw=0.8, color="C3")
    ax_tq.set_ylabel("torque [N m]")
    ax_du.plot(t, tl["duty_frac"], lw=0.8, color="C4")
    ax_du.set_ylabel("duty [-1..1]")
    ax_du.set_ylim(-1.05, 1.05)
    ax_mo.step(t, tl["mode_code"], where="post", color="k", lw=1)
    ax_mo.set_yticks(range(len(MODE_NAMES)), MODE_NAMES, fontsize=7)
    ax_mo.set_ylim(-0.5, len(MODE_NAMES) - 0.5)
    ax_mo.set_ylabel("mode")
    ax_mo.set_xlabel("device time [s]")
    for ax in (ax_th, ax_tq, ax_du):
        ax.tick_params(labelbottom=False)
    for ax in (ax_th, ax_tq, ax_du, ax_mo):
        ax.grid(True, lw=0.3)

    import matplotlib

    cmap = matplotlib.colormaps["viridis"]
    idx = snapshot_indices(len(tl), snapshots)
    for j, k in enumerate(idx):
        x, y = shape_nodes(th[k], l)
        ax_sh.plot(x, y, "-o", ms=3, lw=1.5, color=cmap(j / max(1, len(idx) - 1)), label=f"t = {t[k]:.2f} s")
    L = l * n
    ax_sh.plot([0], [0], "ks", ms=6)
    ax_sh.set_xlim(-1.1 * L, 1.1 * L)
    ax_sh.set_ylim(-1.1 * L, 1.1 * L)
    ax_sh.set_aspect("equal")
    ax_sh.grid(True, lw=0.3)
    ax_sh.set_xlabel("x [m]")
    ax_sh.set_ylabel("y [m]")
    ax_sh.set_title("rod shapes (Fig. 5)" + note, fontsize=9)
    ax_sh.legend(fontsize=7, loc="lower right")

    deg = np.degrees(th)
    for i in range(n):
        ax_f6.plot(t, deg[:, i], lw=0.8, label=f"edge {i + 1}")
    ax_f6.axhline(180.0, color="0.6", ls="--", lw=0.6)
    ax_f6.set_ylabel("edge angle from the downward vertical [deg]")
    ax_f6.set_xlabel("device time [s]")
    ax_f6.set_title("edge angles (Fig. 6; 0 hanging, 180 upright)", fontsize=9)
    ax_f6.grid(True, lw=0.3)

    fw = meta.get("firmware_version", "?")
    fig.suptitle(title or f"{meta.get('port') or meta.get('source', '')}  firmware {fw}  N={n}  "
                 f"{len(data)} frames, {len(tl)} telemetry  parameters {meta.get('params_source', '?')}", fontsize=10)
    return fig


def save_figure(fig, out: str | Path, dpi: int = 110) -> Path:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    out = Path(out)
    FigureCanvasAgg(fig)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, dpi=dpi)
    except OSError as e:
        raise UserError(f"cannot write {out}: {e.strerror or e}") from None
    return out


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


# ---- live --------------------------------------------------------------------------------------

def run_live(args) -> int:
    why = display_problem()
    if why is not None:
        raise UserError(f"plot --live needs a display: {why}. Record instead with "
                        f"`rodctl log --port {args.port or 'PORT'} --out run.csv`, then "
                        "`rodctl plot run.csv --out run.png`")
    import collections

    import matplotlib.pyplot as plt
    from matplotlib.animation import FuncAnimation

    from rodctl.cli.device import design_params, stop_signals
    from rodctl.link.session import Session

    window = args.window
    with stop_signals(), Session(args.port) as s:
        h = s.hello
        n = h.n
        params, _ = design_params(s, args)
        from rodgains.params import load_params

        l = (params or load_params())["rod"]["length"] / n
        keep = int(window * 1e6 / (h.period_us * max(1, h.decimation))) + 10
        buf = collections.deque(maxlen=keep)

        def listen(frame, _t):
            if frame.type == P.MsgType.TELEMETRY:
                m = frame.msg
                buf.append((frame.time_us, m.theta_hat, m.torque, m.duty, int(m.mode)))

        s.add_listener(listen, replay=False)
        fig, axes = plt.subplots(2, 2, figsize=(11, 7))
        (ax_th, ax_sh), (ax_tq, ax_mo) = axes
        lines_th = [ax_th.plot([], [], lw=0.8, label=f"theta_hat_{i + 1}")[0] for i in range(n)]
        ax_th.set_ylabel("angle estimate [rad]")
        ax_th.legend(fontsize=7, loc="upper left")
        line_tq, = ax_tq.plot([], [], color="C3", lw=0.8, label="torque [N m]")
        line_du, = ax_tq.plot([], [], color="C4", lw=0.8, label="duty")
        ax_tq.legend(fontsize=7, loc="upper left")
        ax_tq.set_xlabel("device time [s]")
        line_mo, = ax_mo.step([], [], where="post", color="k")
        ax_mo.set_yticks(range(len(MODE_NAMES)), MODE_NAMES, fontsize=7)
        ax_mo.set_ylim(-0.5, len(MODE_NAMES) - 0.5)
        ax_mo.set_xlabel("device time [s]")
        shape, = ax_sh.plot([], [], "-o", ms=3, lw=2)
        L = l * n
        ax_sh.set_xlim(-1.1 * L, 1.1 * L)
        ax_sh.set_ylim(-1.1 * L, 1.1 * L)
        ax_sh.set_aspect("equal")
        ax_sh.grid(True, lw=0.3)
        title = fig.suptitle(s.port)

        def update(_k):
            s.check()
            rows = list(buf)
            if not rows:
                return []
            tus = np.array([r[0] for r in rows], dtype=np.int64)
            d = np.diff(tus) % (1 << 32)
            t = np.concatenate([[0], np.cumsum(d)]) * 1e-6
            t = t - t[-1]
            th = np.array([r[1] for r in rows])
            for i, ln in enumerate(lines_th):
                ln.set_data(t, th[:, i])
            line_tq.set_data(t, [r[2] for r in rows])
            line_du.set_data(t, [r[3] for r in rows])
            line_mo.set_data(t, [r[4] for r in rows])
            x, y = shape_nodes(th[-1], l)
            shape.set_data(x, y)
            for ax in (ax_th, ax_tq, ax_mo):
                ax.set_xlim(-window, 0)
            ax_th.set_ylim(min(th.min(), 0) - 0.2, max(th.max(), math.pi) + 0.2)
            ax_tq.set_ylim(-1.05, 1.05)
            title.set_text(f"{s.port}  mode {MODE_NAMES[rows[-1][4]] if rows[-1][4] < len(MODE_NAMES) else '?'}")
            return []

        anim = FuncAnimation(fig, update, interval=100, cache_frame_data=False)  # noqa: F841 - keep a reference
        t_end = None if args.duration is None else time.monotonic() + args.duration
        if t_end is not None:
            timer = fig.canvas.new_timer(interval=int(args.duration * 1000))
            timer.add_callback(plt.close, fig)
            timer.start()
        plt.show()
    return 0


# ---- command ------------------------------------------------------------------------------------

def run_plot(args) -> int:
    if args.live:
        return run_live(args)
    if not args.log:
        raise UserError("name a log to plot (rodctl plot run.csv), or --live --port PORT")
    from rodctl.logs.logfile import read_log

    meta, data = read_log(args.log)
    out = args.out
    if out is None and display_problem() is None:
        import matplotlib.pyplot as plt

        fig = plt.figure(figsize=(14, 9), layout="constrained")
        make_figure(meta, data, snapshots=args.snapshots, fig=fig)
        plt.show()
        return 0
    fig = make_figure(meta, data, snapshots=args.snapshots)
    if out is None:
        out = str(Path(args.log).with_suffix("")) + ".png"
        print(f"no display: writing {out}", file=sys.stderr)
    path = save_figure(fig, out)
    rec = f" (recovered from {meta['recovered_from']})" if meta.get("recovered_from") else ""
    print(f"wrote {path}: {len(data)} frames{rec}, panels: {', '.join(PANELS)}")
    return 0


def register(sub) -> None:
    p = sub.add_parser("plot", help="plot a log (time series, rod shapes, edge angles) or a live view",
                       description="Plot a rodctl log: every angle estimate, torque, duty and mode vs time, rod "
                                   "shapes at several times (paper Fig. 5) and every edge angle in degrees (Fig. 6). "
                                   "--out writes a PNG (Agg, works headless); without --out a window opens, or "
                                   "LOG.png is written when there is no display. --live --port P shows the board "
                                   "live (needs a display).")
    p.add_argument("log", nargs="?", metavar="LOG", help="a log written by rodctl log (CSV or Parquet)")
    p.add_argument("--out", metavar="PNG", help="write the figure to this file")
    p.add_argument("--snapshots", type=int, default=6, metavar="K", help="rod shapes to draw (default 6)")
    p.add_argument("--live", action="store_true", help="live view of the board (--port) instead of a log")
    p.add_argument("--port", metavar="PORT", help="with --live: serial port, pyserial URL or sim://")
    p.add_argument("--window", type=float, default=10.0, metavar="S", help="with --live: seconds shown (default 10)")
    p.add_argument("--duration", type=float, metavar="S", help="with --live: close after S seconds")
    p.add_argument("--params", metavar="FILE", help="with --live: parameter file the firmware may come from")
    p.add_argument("--set", metavar="SECTION.KEY=VALUE", action="append", default=[], dest="overrides",
                   help=argparse.SUPPRESS)
    p.set_defaults(func=run_plot)
