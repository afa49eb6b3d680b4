"""Figures of a log: time series, rod shapes at events (paper Fig. 5), edge angles from upright (Fig. 6).

    log = read_log("run.csv", columns=PLOT_COLUMNS)   # only what the figure needs
    fig = make_figure(*log)                            # matplotlib Figure, no backend needed
    save_figure(fig, "run.png")                        # Agg

Angles are shown from the nearest upright (0 = upright whichever way the rod came over, hanging
= -180 deg). Rod shapes are drawn at events (start, catch, the estimate settled: every edge within 2 deg for 0.5 s, fault,
end), not evenly in time.
Long logs are drawn as a min/max envelope per pixel column, so a 1,000,000-frame log plots in
bounded time and memory (see `rodctl bench`, plot_log_mb_per_s).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from rodgains.atomic_file import replacing
from rodgains.errors import InputError

from rodctl.link import protocol as P
from rodctl.logs.metadata import edge_length, overrides_of, params_of
from rodctl.logs.reader import device_time_s, n_edges, theta_hat
from rodctl.logs.schema import from_upright

PANELS = ("angle estimates", "torque", "duty", "mode", "rod shapes at events (Fig. 5)",
          "edge angles from upright (Fig. 6)")
PLOT_COLUMNS = ["time_s", "seq_count", "mode_code", "reason_code", "torque_Nm", "duty_frac", "theta_hat_*"]
MODE_NAMES = [m.name for m in sorted(P.Mode, key=int)]
SETTLE_DEG = 2.0  # every edge within this of upright ...
SETTLE_HOLD_S = 0.5  # ... for this long: "settled"
ENVELOPE_POINTS = 4000  # above this many samples a line is drawn as its min/max per bucket


def shape_nodes(theta: np.ndarray, l: float) -> tuple[np.ndarray, np.ndarray]:
    """Node coordinates [m] (N+1 each, node 0 on the axis) of one rod shape from its edge angles [rad]."""
    th = np.asarray(theta, float)
    x = np.concatenate([[0.0], np.cumsum(l * np.sin(th))])
    y = np.concatenate([[0.0], -np.cumsum(l * np.cos(th))])
    return x, y


def envelope(t: np.ndarray, y: np.ndarray, points: int = ENVELOPE_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """(t, y) reduced to the min and max of each of `points` // 2 buckets (what a pixel column shows)."""
    n = len(t)
    if n <= points:
        return t, y
    k = n // (points // 2)
    m = (n // k) * k
    yb = y[:m].reshape(-1, k)
    tb = t[:m].reshape(-1, k)
    lo, hi = np.nanmin(yb, axis=1), np.nanmax(yb, axis=1)
    tt = np.repeat(tb[:, 0], 2)
    yy = np.column_stack([lo, hi]).ravel()
    return np.concatenate([tt, t[m:]]), np.concatenate([yy, y[m:]])


def break_wraps(t: np.ndarray, y: np.ndarray, jump: float) -> tuple[np.ndarray, np.ndarray]:
    """(t, y) with a NaN between neighbours more than `jump` apart, so that a wrapped angle (179 deg to
    -179 deg is 2 deg of motion) is drawn as a gap, not a line across the panel."""
    cut = np.flatnonzero(np.abs(np.diff(y)) > jump) + 1
    if not cut.size:
        return t, y
    return np.insert(np.asarray(t, float), cut, np.nan), np.insert(np.asarray(y, float), cut, np.nan)


def events_of(mode: np.ndarray, th: np.ndarray, t: np.ndarray) -> list[tuple[str, int]]:
    """(name, row) of the events a snapshot is drawn at: start, catch, settle, fault, end (in time order)."""
    n = len(mode)
    if n == 0:
        return []
    out = [("start", 0)]
    bal = np.flatnonzero(mode == P.Mode.BALANCE)
    if bal.size:
        catch = int(bal[0])
        out.append(("catch", catch))
        tc = t[catch:]
        dev = np.abs(np.degrees(from_upright(th[catch:]))).max(axis=1) if th.shape[1] else np.zeros(len(tc))
        bad = np.concatenate([[0], np.cumsum(dev >= SETTLE_DEG)])
        j = np.searchsorted(tc, tc + SETTLE_HOLD_S)  # first row after each row's hold window
        held = (bad[j] == bad[np.arange(len(tc))]) & (tc[np.maximum(j - 1, 0)] - tc >= 0.99 * SETTLE_HOLD_S)
        if held.any():
            out.append(("estimate settled", catch + int(np.argmax(held))))  # the log has no truth: not the sim's rule
    fault = np.flatnonzero(mode == P.Mode.FAULT)
    if fault.size:
        out.append(("fault", int(fault[0])))
    if out[-1][1] != n - 1:
        out.append(("end", n - 1))
    merged: dict[int, str] = {}
    for name, k in sorted(out, key=lambda e: e[1]):  # one snapshot per row: "start + catch" when they coincide
        merged[k] = f"{merged[k]} + {name}" if k in merged else name
    return [(name, k) for k, name in merged.items()]


def title_of(meta: dict, rows: int) -> str:
    over = meta.get("overrides")
    if over is None:
        over = " ".join(overrides_of(params_of(meta)))
    src = meta.get("port") or meta.get("source", "")
    text = (f"{src}  firmware {meta.get('firmware_version', '?')}  {rows} telemetry frames  "
            f"parameters {meta.get('params_source', '?')}")
    return text + (f"\noverrides: {over}" if over else "  (no overrides)")


def make_figure(meta: dict, data: np.ndarray, snapshots: int = 6, title: str | None = None, fig=None):
    """The log's Figure (matplotlib.figure.Figure, 6 axes: see PANELS); draws into `fig` when given."""
    import matplotlib
    from matplotlib.figure import Figure

    tl = data
    n = n_edges(tl)
    if len(tl) == 0:
        raise InputError("the log has no telemetry rows to plot")
    t = device_time_s(tl)
    th = theta_hat(tl)
    mode = np.asarray(tl["mode_code"])
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
        ax_th.plot(*envelope(t, th[:, i]), lw=0.8, label=f"theta_hat_{i + 1}")
    finite = th[np.isfinite(th)]  # a damaged cell (inf) draws as a gap, and must not set the upright lines' range
    if finite.size:
        lo, hi = finite.min(), finite.max()
        for k in range(round((lo - math.pi) / (2 * math.pi)), round((hi - math.pi) / (2 * math.pi)) + 1):
            ax_th.axhline(math.pi + 2 * math.pi * k, color="0.6", ls="--", lw=0.6)
    ax_th.set_ylabel("angle estimate [rad]")
    ax_th.set_title("angle estimates (dashed: upright, pi + 2 pi k)", fontsize=9)
    if n <= 10:  # beside the panel: inside, it covers the curves it names
        ax_th.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.005, 1.0), borderaxespad=0.0)

    ax_tq.plot(*envelope(t, np.asarray(tl["torque_Nm"], float)), lw=0.8, color="C3")
    ax_tq.set_ylabel("torque [N m]")
    ax_du.plot(*envelope(t, np.asarray(tl["duty_frac"], float)), lw=0.8, color="C4")
    ax_du.set_ylabel("duty [-1..1]")
    ax_du.set_ylim(-1.05, 1.05)
    ch = np.concatenate([[0], np.flatnonzero(np.diff(mode)) + 1, [len(mode) - 1]])  # a step plot needs only changes
    ax_mo.step(t[ch], mode[ch], where="post", color="k", lw=1)
    ax_mo.set_yticks(range(len(MODE_NAMES)), MODE_NAMES, fontsize=7)
    ax_mo.set_ylim(-0.5, len(MODE_NAMES) - 0.5)
    ax_mo.set_ylabel("mode")
    ax_mo.set_xlabel("device time [s]")
    for ax in (ax_th, ax_tq, ax_du):
        ax.tick_params(labelbottom=False)
    for ax in (ax_th, ax_tq, ax_du, ax_mo):
        ax.grid(True, lw=0.3)

    cmap = matplotlib.colormaps["viridis"]
    events = events_of(mode, th, t)[:max(1, snapshots)]
    for j, (name, k) in enumerate(events):
        x, y = shape_nodes(th[k], l)
        c = cmap(j / max(1, len(events) - 1))
        ax_sh.plot(x, y, "-o", ms=3, lw=1.5, color=c, label=f"{name}, t = {t[k]:.2f} s")
        for ax in (ax_th, ax_mo):
            ax.axvline(t[k], color=c, lw=0.6, ls=":")
    L = l * n
    ax_sh.plot([0], [0], "ks", ms=6)
    ax_sh.set_xlim(-1.1 * L, 1.1 * L)
    ax_sh.set_ylim(-1.1 * L, 1.1 * L)
    ax_sh.set_aspect("equal")
    ax_sh.grid(True, lw=0.3)
    ax_sh.set_xlabel("x [m]")
    ax_sh.set_ylabel("y [m]")
    ax_sh.set_title("rod shapes at events (Fig. 5)" + note, fontsize=9)
    ax_sh.legend(fontsize=7, loc="lower right")

    dev = np.degrees(from_upright(th))
    for i in range(n):
        ax_f6.plot(*break_wraps(*envelope(t, dev[:, i]), jump=180.0), lw=0.8, label=f"edge {i + 1}")
    ax_f6.axhline(0.0, color="0.6", ls="--", lw=0.6)
    ax_f6.set_ylim(-185, 185)
    ax_f6.set_yticks(range(-180, 181, 45))
    ax_f6.set_ylabel("edge angle from upright [deg]")
    ax_f6.set_xlabel("device time [s]")
    ax_f6.set_title("edge angles from upright (Fig. 6; +-180 hanging)", fontsize=9)
    ax_f6.grid(True, lw=0.3)

    fig.suptitle(title or title_of(meta, len(tl)), fontsize=10)
    return fig


def save_figure(fig, out: str | Path, dpi: int = 110) -> Path:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    out = Path(out)
    FigureCanvasAgg(fig)
    try:
        with replacing(out) as tmp:  # whole or not at all: a failed draw leaves no cut figure
            fig.savefig(tmp, dpi=dpi, format=out.suffix.lstrip(".").lower() or "png")
    except OSError as e:
        raise InputError(f"cannot write {out}: {e.strerror or e}") from None
    return out
