"""Figures like the paper's Figs. 5 and 6: the tracked shape against the estimated one at chosen
times, and every edge's angle over time, tracked against estimated."""

from __future__ import annotations

import numpy as np


def _nodes(theta: np.ndarray, length: float) -> np.ndarray:
    l = length / len(theta)
    d = np.column_stack([np.sin(theta) * l, -np.cos(theta) * l])
    return np.vstack([np.zeros(2), np.cumsum(d, axis=0)])


def tracking_figure(t: np.ndarray, tracked: np.ndarray, estimate: np.ndarray, length: float, times: list[float],
                    title: str):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = tracked.shape[1]
    fig = plt.figure(figsize=(11, 7.5))
    gs = fig.add_gridspec(2, max(1, len(times)), height_ratios=[1, 1.3])
    for j, tj in enumerate(times):
        ax = fig.add_subplot(gs[0, j])
        k = int(np.nanargmin(np.abs(t - tj)))
        for th, style, label in ((tracked[k], "-o", "video"), (estimate[k], "--s", "estimate")):
            if np.all(np.isfinite(th)):
                p = _nodes(th, length) * 100
                ax.plot(p[:, 0], p[:, 1], style, ms=3, label=label)
        ax.set_aspect("equal")
        lim = length * 110
        ax.set_xlim(-lim, lim)
        ax.set_ylim(-lim, lim)
        ax.set_title(f"t = {t[k]:.2f} s", fontsize=9)
        ax.set_xlabel("x [cm]")
        if j == 0:
            ax.set_ylabel("y [cm]")
            ax.legend(fontsize=8, loc="lower left")
    ax = fig.add_subplot(gs[1, :])
    colors = plt.cm.viridis(np.linspace(0, 0.9, n))
    for i in range(n):
        ax.plot(t, np.degrees(tracked[:, i]), color=colors[i], lw=1.2, label=f"theta_{i + 1}" if i in (0, n - 1) else None)
        ax.plot(t, np.degrees(estimate[:, i]), color=colors[i], lw=0.8, ls="--")
    ax.set_xlabel("time on the log's clock [s]")
    ax.set_ylabel("edge angle [deg] (0 hanging)")
    ax.set_title("solid: video, dashed: the board's estimate", fontsize=9)
    ax.legend(fontsize=8, loc="upper left")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig
