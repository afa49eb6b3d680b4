"""The board's estimate against the rod the camera saw: per-edge error, RMS, peak and after settling."""

from __future__ import annotations

import numpy as np

SETTLE_AFTER_S = 1.0  # "after settling": from this long after the first BALANCE frame [s]
MODE_BALANCE = 1


def wrap(a: np.ndarray) -> np.ndarray:
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def on_branch(tracked: np.ndarray, estimate: np.ndarray) -> np.ndarray:
    """The tracked angles moved by whole turns onto the estimate's branch (the board counts its own turns,
    the camera its own); where there is no estimate (a frame outside the log) they stay as they are."""
    turns = np.round((estimate - tracked) / (2 * np.pi))
    return tracked + 2 * np.pi * np.where(np.isfinite(turns), turns, 0.0)


def estimate_at(t: np.ndarray, t_log: np.ndarray, theta_hat: np.ndarray) -> np.ndarray:
    """The log's theta_hat (absolute, pi upright) at times t, per edge; NaN outside the log."""
    out = np.column_stack([np.interp(t, t_log, theta_hat[:, i], left=np.nan, right=np.nan)
                           for i in range(theta_hat.shape[1])])
    return out


def settle_time(t_log: np.ndarray, mode: np.ndarray) -> float | None:
    """The log time from which the estimate counts as settled (first BALANCE + SETTLE_AFTER_S)."""
    bal = np.flatnonzero(mode == MODE_BALANCE)
    return float(t_log[bal[0]]) + SETTLE_AFTER_S if bal.size else None


def error_table(t: np.ndarray, tracked: np.ndarray, estimate: np.ndarray, settled_from: float | None) -> list[dict]:
    """Per edge: RMS and peak of (estimate - tracked) [deg] over every frame both have, and the RMS
    after settling (None when the run never balanced in the video)."""
    err = np.degrees(wrap(estimate - tracked))
    rows = []
    for i in range(err.shape[1]):
        e = err[:, i]
        ok = np.isfinite(e)
        after = ok & (t >= settled_from) if settled_from is not None else np.zeros_like(ok)
        rows.append({"edge": i + 1, "frames": int(ok.sum()),
                     "rms_deg": float(np.sqrt(np.mean(e[ok] ** 2))) if ok.any() else float("nan"),
                     "peak_deg": float(np.max(np.abs(e[ok]))) if ok.any() else float("nan"),
                     "settled_rms_deg": float(np.sqrt(np.mean(e[after] ** 2))) if after.any() else None})
    return rows


def table_lines(rows: list[dict]) -> list[str]:
    out = [f"{'edge':>4} {'frames':>6} {'RMS [deg]':>9} {'peak [deg]':>10} {'settled RMS [deg]':>17}"]
    for r in rows:
        s = "-" if r["settled_rms_deg"] is None else f"{r['settled_rms_deg']:.2f}"
        out.append(f"{r['edge']:>4} {r['frames']:>6} {r['rms_deg']:>9.2f} {r['peak_deg']:>10.2f} {s:>17}")
    return out
