"""Figures read at a glance: the robustness heatmap (case x metric) and the sweep frontier."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rodgains.atomic_file import replacing

# metric key, column title, digits
HEAT_METRICS = (
    ("settle_s", "settle 1 deg [s]", 2),
    ("final_dev_deg", "final [deg]", 2),
    ("max_dev_deg", "peak error [deg]", 1),
    ("peak_torque_Nm", "peak torque [N m]", 3),
    ("caught_at_s", "caught [s]", 2),
    ("base_turns_max", "base turns", 2),
    ("est_rms_deg", "est. error [deg]", 2),
    ("buckling_ratio", "rod / buckling length", 3),  # past 1: a still shaft cannot hold it (rodgains.buckling)
)


def _value(row: dict, key: str) -> float:
    v = row.get(key)
    return math.nan if v is None else float(v)


def _verdict(row: dict) -> tuple[str, str]:
    if row.get("refused"):
        return "refused", "#9e9e9e"
    return ("pass", "#2e7d32") if row.get("passed") else ("FAIL", "#c62828")


HEAT_SPAN = (0.15, 0.85)  # the part of the colour map a cell uses: its ends are too light or dark for text


def heatmap(rows: list[dict], path: Path, title: str) -> Path:
    """heatmap_figure, written to `path` (PNG, or the format of its extension)."""
    return _write(heatmap_figure(rows, title), path)


def heatmap_figure(rows: list[dict], title: str):
    """One panel per task: a row per case (and Monte Carlo draw), a column per metric. Each column is
    coloured on its own scale (lighter = smaller = better for every metric here), as the colour key
    under the panels says; the first column says pass / FAIL / refused; empty cells are runs where the
    metric does not exist (never settled, not a swing-up)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import ListedColormap, Normalize

    from rodctl.sim.matrix import marks

    tasks = list(dict.fromkeys(r["task"] for r in rows))
    height = max(len([r for r in rows if r["task"] == t]) for t in tasks)
    # constrained layout: tight_layout cannot fit the rotated labels of a short matrix and warns
    fig, axes = plt.subplots(1, len(tasks), figsize=(7.2 * len(tasks), max(3.4, 1.6 + 0.22 * height)), squeeze=False,
                             layout="constrained")
    cmap = matplotlib.colormaps["viridis_r"]
    for ax, task in zip(axes[0], tasks):
        sub = [r for r in rows if r["task"] == task]
        always = {"settle_s"} | ({"caught_at_s"} if task == "swingup" else set())
        cols = [m for m in HEAT_METRICS if m[0] in always or any(r.get(m[0]) is not None for r in sub)]
        M = np.array([[_value(r, k) for k, _, _ in cols] for r in sub], dtype=float).reshape(len(sub), len(cols))
        for j in range(M.shape[1]):
            col = M[:, j]
            fin = np.isfinite(col)
            lo, hi = (np.min(col[fin]), np.max(col[fin])) if fin.any() else (0.0, 1.0)
            for i in range(M.shape[0]):
                if fin[i]:
                    f = 0.5 if hi == lo else (col[i] - lo) / (hi - lo)
                    ax.add_patch(plt.Rectangle((j + 1, i), 1, 1, color=cmap(HEAT_SPAN[0] + (HEAT_SPAN[1] - HEAT_SPAN[0]) * f)))
                    ax.text(j + 1.5, i + 0.5, f"{col[i]:.{cols[j][2]}f}", ha="center", va="center", fontsize=6.5,
                            color="white" if f > 0.45 else "black")
                else:
                    ax.add_patch(plt.Rectangle((j + 1, i), 1, 1, color="#eeeeee"))
                    ax.text(j + 1.5, i + 0.5, "never" if cols[j][0] in ("settle_s", "caught_at_s") else "-",
                            ha="center", va="center", fontsize=6, color="#777777")
        for i, r in enumerate(sub):
            word, color = _verdict(r)
            ax.add_patch(plt.Rectangle((0, i), 1, 1, color=color))
            ax.text(0.5, i + 0.5, word, ha="center", va="center", fontsize=7, color="white", weight="bold")
        ax.set_xlim(0, len(cols) + 1)
        ax.set_ylim(len(sub), 0)
        ax.set_xticks(np.arange(len(cols) + 1) + 0.5)
        ax.set_xticklabels(["result"] + [c[1] for c in cols], rotation=35, ha="right", fontsize=7)
        ax.set_yticks(np.arange(len(sub)) + 0.5)
        ax.set_yticklabels([r["case"] + marks(r) for r in sub], fontsize=7)
        ax.tick_params(length=0)
        n_pass = sum(1 for r in sub if r.get("passed"))
        ax.set_title(f"{task}: {n_pass}/{len(sub)} pass", fontsize=9)
        for s in ax.spines.values():
            s.set_visible(False)
    key = ListedColormap(cmap(np.linspace(*HEAT_SPAN, 256)))
    bar = fig.colorbar(ScalarMappable(Normalize(0.0, 1.0), key), ax=axes[0].tolist(), orientation="horizontal",
                       shrink=0.6, aspect=50, pad=0.01)
    bar.set_ticks([0.0, 1.0], labels=["smallest in its column: better", "largest in its column: worse"], fontsize=7)
    bar.set_label("cell colour: each metric on its own scale (grey: no value)", fontsize=7)
    fig.suptitle(title, fontsize=10)
    return fig


def frontier_figure(rows: list[dict], x: str, y: str | None, path: Path, title: str, *, color_key: str = "settle_s",
                    color_label: str = "settle to 1 deg [s]", critical_length_m: float | None = None) -> Path:
    """Grid x (horizontal) by y (vertical): the colour is `color_key` where the run passed, a red cross
    where it failed, grey R where the design was refused; a black line joins, for each y, the largest x
    that passed with every smaller x passing (the frontier). With x = rod.length, a dashed line marks
    the continuum critical length."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = _columns(rows, x)
    ys = sorted({r[y] for r in rows}) if y else [None]
    shade = _shading(rows, color_key)
    fig, ax = plt.subplots(figsize=(8.0, 2.0 + 0.45 * len(ys)))
    for r in rows:
        _draw_point(ax, r, (cols.at(r[x]), ys.index(r[y]) if y else 0), cols.width, shade)
    if y and not isinstance(cols.values[0], str):
        _draw_frontier(ax, rows, x, y, ys, cols)
    marked = critical_length_m is not None and x == "rod.length" and cols.numeric
    _frame(ax, cols, x, y, ys, marked)
    if marked:  # after the frame: its words go left or right of the line within the limits
        _mark_critical_length(ax, critical_length_m, len(ys))
    sm = matplotlib.cm.ScalarMappable(cmap=shade.cmap, norm=matplotlib.colors.Normalize(0, shade.vmax))
    fig.colorbar(sm, ax=ax, label=color_label, pad=0.02)
    if marked:
        _critical_ratio_axis(ax, critical_length_m)
    legend = ("black bar: frontier (largest passing, no failure below); x: fail; R: design refused"
              + ("" if shade.graded else "; green: passed, never within 1 deg"))
    ax.set_title(title + "\n" + legend, fontsize=8)
    fig.tight_layout()
    return _write(fig, path, bbox_inches="tight")


@dataclass(frozen=True)
class _Columns:
    """The x values across the frontier figure: an evenly spaced numeric axis is drawn to scale, anything
    else (strings, 5,10,20) one column per value."""

    values: list  # sorted
    numeric: bool  # drawn to scale
    width: float  # of a column [x units when numeric, else 1]
    index: dict  # value -> its column when not to scale

    def at(self, v) -> float:
        """The centre of v's column on the figure's x axis."""
        return v if self.numeric else self.index[v]


def _columns(rows: list[dict], x: str) -> _Columns:
    xs = sorted({r[x] for r in rows})
    steps = np.diff(np.asarray(xs, dtype=float)) if not isinstance(xs[0], str) and len(xs) > 1 else np.array([])
    numeric = not isinstance(xs[0], str) and (len(xs) == 1 or bool(np.allclose(steps, steps[0])))
    dx = float(steps[0]) if numeric and len(xs) > 1 else 1.0
    return _Columns(xs, numeric, dx, {v: i for i, v in enumerate(xs)})


@dataclass(frozen=True)
class _Shading:
    """How a grid point's `key` colours its cell."""

    key: str
    graded: bool  # the score: it colours every point, a run metric only the runs that passed
    cmap: object
    vmax: float  # the top of the colour scale [key's unit]

    def colour(self, value: float):
        return self.cmap(value / self.vmax if self.vmax else 0)


def _shading(rows: list[dict], key: str) -> _Shading:
    import matplotlib

    graded = key == "score"
    vals = [r.get(key) for r in rows if (graded or r.get("passed")) and r.get(key) is not None]
    vmax = 1.0 if graded or not vals else max(vals)
    # lighter is better in both: a short settle time, a high score
    return _Shading(key, graded, matplotlib.colormaps["viridis" if graded else "viridis_r"], vmax)


def _draw_point(ax, row: dict, centre: tuple[float, float], width: float, shade: _Shading) -> None:
    """One grid point's cell: grey R (refused), its score, its colour (passed), green "pass" (passed
    without settling to 1 deg), or a red cross (failed)."""
    cx, cy = centre
    value = row.get(shade.key)
    if row.get("refused"):
        _cell(ax, centre, width, "#bdbdbd")
        ax.text(cx, cy, "R", ha="center", va="center", fontsize=7, color="#555555")
    elif shade.graded and value is not None:
        _cell(ax, centre, width, shade.colour(value))
        ax.text(cx, cy, f"{value:.2f}", ha="center", va="center", fontsize=6,
                color="white" if value < 0.55 else "black")
    elif row.get("passed") and value is not None:
        _cell(ax, centre, width, shade.colour(value))
    elif row.get("passed"):
        _cell(ax, centre, width, "#c8e6c9")
        ax.text(cx, cy, "pass", ha="center", va="center", fontsize=6, color="#2e7d32")
    else:
        _cell(ax, centre, width, "#fbe9e7")
        ax.plot([cx], [cy], marker="x", color="#c62828", ms=7, mew=1.5)


def _cell(ax, centre: tuple[float, float], width: float, color) -> None:
    import matplotlib.pyplot as plt

    cx, cy = centre
    ax.add_patch(plt.Rectangle((cx - width / 2, cy - 0.5), width, 1, color=color))


def _draw_frontier(ax, rows: list[dict], x: str, y: str, ys: list, cols: _Columns) -> None:
    """A black bar, for each y, at the right edge of the frontier's column (none where nothing passed)."""
    from rodctl.robust.sweep import frontier

    fr = frontier(rows, x, y)
    fx = [cols.at(fr[v]) + cols.width / 2 if fr[v] is not None else None for v in ys]
    for i, v in enumerate(fx):
        if v is not None:
            ax.plot([v, v], [i - 0.5, i + 0.5], color="black", lw=2.2)


def _mark_critical_length(ax, length_m: float, n_rows: int) -> None:
    ax.axvline(length_m, color="black", ls="--", lw=1)
    # right of the line, or left of it where the line is in the plot's right half: the words stay inside
    right = length_m > sum(ax.get_xlim()) / 2
    ax.text(length_m, n_rows - 0.45, f"continuum critical length {length_m * 100:.2f} cm ",
            fontsize=7, va="bottom", ha="right" if right else "left", clip_on=True)


def _frame(ax, cols: _Columns, x: str, y: str | None, ys: list, marked: bool) -> None:
    """Limits, ticks and labels; a critical length mark gets half a row above the grid for its words."""
    if cols.numeric:
        ax.set_xlim(cols.values[0] - cols.width / 2, cols.values[-1] + cols.width / 2)
    else:
        ax.set_xlim(-0.5, len(cols.values) - 0.5)
        ax.set_xticks(range(len(cols.values)))
        ax.set_xticklabels(cols.values)
    ax.set_ylim(-0.5, len(ys) - 0.5 + (0.5 if marked else 0))
    ax.set_yticks(range(len(ys)))
    ax.set_yticklabels([str(v) for v in ys] if y else [""])
    ax.set_xlabel(_with_unit(x))
    if y:
        ax.set_ylabel(_with_unit(y))


def _with_unit(name: str) -> str:
    """A swept key as an axis label with its unit: rod.length [m]."""
    from rodgains.params import SCHEMA

    section, _, key = name.partition(".")
    unit = SCHEMA.get(section, {}).get(key).unit if key in SCHEMA.get(section, {}) else ""
    return f"{name} [{unit}]" if unit and unit != "-" else name


def _critical_ratio_axis(ax, length_m: float) -> None:
    """A top axis in units of the continuum critical length."""
    top = ax.secondary_xaxis("top", functions=(lambda v: v / length_m, lambda r: r * length_m))
    top.set_xlabel("length / continuum critical length", fontsize=8)
    top.tick_params(labelsize=7)


def _write(fig, path: Path, **savefig) -> Path:
    """The figure to `path` (PNG, or the format of its extension), replacing any file there; closes it."""
    import matplotlib.pyplot as plt

    path = Path(path)
    with replacing(path) as tmp:
        fig.savefig(tmp, dpi=130, format=path.suffix.lstrip(".") or "png", **savefig)
    plt.close(fig)
    return path
