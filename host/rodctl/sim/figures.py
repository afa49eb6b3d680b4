"""Figures of a scenario: rod-shape snapshots (like the paper's Fig. 5) and time series (Figs. 3 and 6)."""

from __future__ import annotations

import math
import textwrap

import numpy as np

from rodctl.logs.plots import shape_nodes
from rodctl.logs.metadata import overrides_of
from rodctl.sim.scenarios import SETTLE_DEG, Outcome, Trace, resample_edges

TITLE_CHARS_PER_INCH = 13  # characters of a 10-point title that fit an inch of figure, with margin

COLORS = ["#1f77b4", "#d62728", "#e6a800", "#2ca02c", "#9467bd", "#8c564b"]


def snapshot_times(tr: Trace, k: int, after: float = 2.0) -> list[int]:
    """k indices from the start to `after` seconds past the controller taking over (or the end)."""
    t_end = min(tr.t[-1], tr.start + after)
    i1 = int(np.searchsorted(tr.t, t_end, side="right")) - 1
    return [int(round(v)) for v in np.linspace(0, max(i1, 1), k)]


def continuous_deviation_deg(tr: Trace) -> np.ndarray:
    """theta - upright in degrees without wrapping, upright taken as the one each edge ends nearest."""
    th = np.unwrap(tr.theta, axis=0)
    up = np.pi + 2 * np.pi * np.round((th[-1] - np.pi) / (2 * np.pi))
    return np.degrees(th - up)


def make_figure(o: Outcome, snapshots: int = 6):
    """The scenario's figure: snapshots on top, then angles, torque and (firmware runs) estimate error."""
    from matplotlib.figure import Figure

    firmware = [tr for tr in o.traces if tr.est is not None]
    rows = 3 + (1 if firmware else 0)
    width = 12  # [in]
    fig = Figure(figsize=(width, 2.4 + 2.2 * (rows - 1)), layout="constrained")
    gs = fig.add_gridspec(rows, snapshots, height_ratios=[1.3] + [1] * (rows - 1))
    over = " ".join(overrides_of(o.params))
    lines = [f"{o.name}: {o.title}", f"{'PASS' if o.passed else 'FAIL'}: {o.criterion}"]
    if over:
        lines.append(f"overrides: {over}")
    # wrapped to the figure's width: a long override list was cut off at both sides
    fig.suptitle("\n".join(textwrap.fill(ln, TITLE_CHARS_PER_INCH * width) for ln in lines), fontsize=10)

    def lengths(tr):  # edge lengths [m]: a faithful plant's hub differs from its other edges
        return np.diff(tr.node_arc) if tr.node_arc is not None else tr.edge_length

    L = max(float(np.sum(np.broadcast_to(lengths(tr), tr.theta.shape[1:]))) for tr in o.traces)
    ref = o.traces[0]
    idx = snapshot_times(ref, snapshots)
    for j, k in enumerate(idx):
        ax = fig.add_subplot(gs[0, j])
        for c, tr in enumerate(o.traces):
            kk = min(k, len(tr.t) - 1)
            x, y = shape_nodes(tr.theta[kk], lengths(tr))
            ax.plot(x, y, "-o", ms=2, lw=1.6, color=COLORS[c % len(COLORS)], label=tr.label if j == 0 else None)
            if tr.est is not None and tr.mode is not None and tr.mode[kk] == 1:
                n = tr.est.shape[1] // 2
                xe, ye = shape_nodes(tr.est[kk, :n], L / n)
                ax.plot(xe, ye, "--", lw=1.2, color="k", alpha=0.7, label="estimate" if j == 0 else None)
        ax.set_xlim(-1.1 * L, 1.1 * L)
        ax.set_ylim(-1.1 * L, 1.1 * L)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(f"t = {ref.t[k]:.2f} s", fontsize=8)
        ax.plot([0], [0], "ks", ms=4)
    fig.axes[0].legend(fontsize=6, loc="lower left")

    ax_th = fig.add_subplot(gs[1, :])
    for c, tr in enumerate(o.traces):
        dev = continuous_deviation_deg(tr)
        color = COLORS[c % len(COLORS)]
        for i in range(dev.shape[1]):
            ax_th.plot(tr.t, dev[:, i], lw=0.8 if i else 1.4, color=color, alpha=0.35 + 0.65 * (i == 0),
                       label=f"{tr.label}: theta_1 (bold) .. theta_{dev.shape[1]}" if i == 0 else None)
        if tr.caught_at is not None:
            ax_th.axvline(tr.caught_at, color="r", lw=1.2, label="switch to balance")
    ax_th.axhspan(-SETTLE_DEG, SETTLE_DEG, color="0.85", zorder=0)
    ax_th.set_ylabel("edge angle from upright [deg]")
    peak = max(float(np.nanmax(np.abs(continuous_deviation_deg(tr)))) for tr in o.traces)
    lim = max(40.0, min(400.0, 1.05 * peak))
    ax_th.set_ylim(-lim, lim)
    ax_th.legend(fontsize=7, loc="upper right")

    ax_u = fig.add_subplot(gs[2, :], sharex=ax_th)
    for c, tr in enumerate(o.traces):
        ax_u.plot(tr.t, tr.torque, lw=0.9, color=COLORS[c % len(COLORS)], label=tr.label)
    ax_u.set_ylabel("base torque [N m]")

    if firmware:
        ax_e = fig.add_subplot(gs[3, :], sharex=ax_th)
        tr = firmware[0]
        n = tr.est.shape[1] // 2
        err = np.degrees(np.mod(tr.est[:, :n] - resample_edges(tr.theta, n, tr.node_arc) + np.pi, 2 * np.pi) - np.pi)
        err[tr.mode != 1] = np.nan
        for i in range(n):
            ax_e.plot(tr.t, err[:, i], lw=0.8, label=f"edge {i + 1}")
        ax_e.set_ylabel("estimate - true [deg]" if len(firmware) == 1 else f"{tr.label}: estimate - true [deg]")
        # above the panel: inside, it covered the error right after the catch
        ax_e.legend(fontsize=6, ncol=min(n, 10), loc="lower right", bbox_to_anchor=(1.0, 1.0), borderaxespad=0.2,
                    frameon=False)
        ax_e.set_xlabel("time [s]")
        finite = err[np.isfinite(err)]
        if finite.size:  # the whole error, its trough right after the catch included
            span = max(1.0, float(np.max(np.abs(finite))) * 1.1)
            ax_e.set_ylim(-span, span)
    else:
        ax_u.set_xlabel("time [s]")
    return fig


def save(o: Outcome, path) -> None:
    fig = make_figure(o)
    fig.savefig(path, dpi=100)


def fmt(v: float, digits: int = 2) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if isinstance(v, float) and math.isinf(v):
        return "never"
    return f"{v:.{digits}f}"
