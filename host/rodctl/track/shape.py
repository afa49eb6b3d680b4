"""From marker centroids to the rod's shape: the hub, the scale, each marker's place along the rod,
and every edge's angle in the design model's discretization.

Markers: one on the motor axis (it does not move with the rod), and `markers` more spaced equally
along the rod, the last at the tip (arc length i L / markers from the axis). The design model's
N equal edges run from the axis to the tip; theta_k is the absolute angle of the chord between arc
lengths (k - 1) L / N and k L / N, 0 hanging, counter-clockwise positive (seen by the camera).
"""

from __future__ import annotations

import numpy as np

from rodgains.errors import InputError

# per-frame quality flags
GOOD, FILLED, UNUSABLE, REPEATED = 0, 1, 2, 3
QUALITY_TEXT = {GOOD: "every marker seen", FILLED: "a marker filled in from its neighbours",
                UNUSABLE: "too few markers", REPEATED: "a repeated (dropped) frame"}

HUB_TOL_PX = 3.0  # a marker this close to the same place in most frames is the hub's


def find_hub(dets: list[np.ndarray], share: float = 0.8) -> np.ndarray | None:
    """The image point [px] where a marker sits in at least `share` of the frames (the axis), or None."""
    step = max(1, len(dets) // 400)
    sample = [d for d in dets[::step]]
    if not sample:
        return None
    pts = [(i, p) for i, d in enumerate(sample) for p in d]
    if not pts:
        return None
    frames = np.array([i for i, _ in pts])
    xy = np.array([p for _, p in pts])
    cells = np.floor(xy / HUB_TOL_PX).astype(np.int64)
    keys = cells[:, 0] * 1_000_003 + cells[:, 1]
    best, best_n = None, 0
    for key in np.unique(keys):
        sel = keys == key
        c = xy[sel].mean(axis=0)
        near = np.linalg.norm(xy - c, axis=1) <= HUB_TOL_PX
        n = len(np.unique(frames[near]))
        if n > best_n:
            best, best_n = xy[near].mean(axis=0), n
    return best if best_n >= share * len(sample) else None


def order_from_hub(points: np.ndarray, hub: np.ndarray) -> np.ndarray:
    """The markers as a chain from the hub: each next one the nearest not yet taken."""
    left = list(range(len(points)))
    out, cur = [], hub
    while left:
        d = [np.hypot(*(points[j] - cur)) for j in left]
        j = left.pop(int(np.argmin(d)))
        out.append(j)
        cur = points[j]
    return points[out]


def rod_markers(frame_dets: np.ndarray, hub: np.ndarray) -> np.ndarray:
    """This frame's markers on the rod, ordered from the hub (the hub's own marker left out)."""
    if not len(frame_dets):
        return frame_dets
    away = np.linalg.norm(frame_dets - hub, axis=1) > 2 * HUB_TOL_PX
    return order_from_hub(frame_dets[away], hub)


def chain_length(ordered: np.ndarray, hub: np.ndarray) -> float:
    pts = np.vstack([hub, ordered])
    return float(np.sum(np.hypot(*np.diff(pts, axis=0).T)))


def rod_length_px(dets: list[np.ndarray], hub: np.ndarray, markers: int) -> float:
    """The rod's length in the image [px]: the median chain length of the frames showing every marker."""
    lengths = []
    step = max(1, len(dets) // 2000)
    for d in dets[::step]:
        m = rod_markers(d, hub)
        if len(m) == markers:
            lengths.append(chain_length(m, hub))
    if len(lengths) < 3:
        raise InputError(f"never saw all {markers} markers of the rod in one frame: pass --markers with the "
                         "number on the rod (besides the one on the axis), or --scale")
    return float(np.median(lengths))


def place(ordered: np.ndarray, hub: np.ndarray, markers: int, spacing_px: float) -> tuple[np.ndarray, int]:
    """Each seen marker's index along the rod (1..markers, from its distance along the chain);
    returns (positions [markers + 1, 2] px with NaN where not seen, quality)."""
    pos = np.full((markers + 1, 2), np.nan)
    pos[0] = hub
    if len(ordered) == 0:
        return pos, UNUSABLE
    d = np.cumsum(np.hypot(*np.diff(np.vstack([hub, ordered]), axis=0).T))
    last = 0
    for p, dist in zip(ordered, d):
        i = int(round(dist / spacing_px))
        i = max(i, last + 1)  # a missing marker shortens the chain: never go back
        if i > markers:
            break
        pos[i] = p
        last = i
    seen = ~np.isnan(pos[:, 0])
    if seen.sum() - 1 < max(2, markers - 2) or not seen[-1]:
        return pos, UNUSABLE
    if not seen.all():
        # the rod is smooth: a cubic spline in arc length through the markers seen fills a hidden one
        from scipy.interpolate import CubicSpline

        idx = np.arange(markers + 1)
        for c in range(2):
            pos[~seen, c] = CubicSpline(idx[seen], pos[seen, c])(idx[~seen])
        return pos, FILLED
    return pos, GOOD


def to_world(pos_px: np.ndarray, hub: np.ndarray, m_per_px: float) -> np.ndarray:
    """Image [px] (v down) -> world [m] (x right, y up), the axis at 0."""
    out = np.empty_like(pos_px)
    out[..., 0] = (pos_px[..., 0] - hub[0]) * m_per_px
    out[..., 1] = -(pos_px[..., 1] - hub[1]) * m_per_px
    return out


def edge_angles(pos_m: np.ndarray, length: float, edges: int) -> np.ndarray:
    """theta_1..theta_N [rad] of the design model's N equal edges, from marker positions [m] at arc
    lengths i L / markers (i = 0 .. markers), each row a frame; NaN rows stay NaN."""
    markers = pos_m.shape[-2] - 1
    s_m = np.linspace(0.0, length, markers + 1)
    s_n = np.linspace(0.0, length, edges + 1)
    x = np.stack([np.interp(s_n, s_m, row) if np.all(np.isfinite(row)) else np.full(edges + 1, np.nan)
                  for row in pos_m[..., 0]])
    y = np.stack([np.interp(s_n, s_m, row) if np.all(np.isfinite(row)) else np.full(edges + 1, np.nan)
                  for row in pos_m[..., 1]])
    return np.arctan2(np.diff(x, axis=1), -np.diff(y, axis=1))


BASE_FIT_MARKERS = 3  # markers beyond the axis in the base tangent's fit


def base_tangent(pos_m: np.ndarray, length: float) -> np.ndarray:
    """The rod's tangent where it leaves the axis [rad] per frame: the slope at s = 0 of a quadratic in
    arc length through the axis and the first BASE_FIT_MARKERS markers. A clamped rod leaves the shaft
    along the shaft's angle, so this follows the output shaft, where the first edge's chord also
    carries the bend of the rod's foot (in a swing-up, a few degrees that come and go)."""
    markers = pos_m.shape[-2] - 1
    k = min(markers, BASE_FIT_MARKERS) + 1
    s = np.linspace(0.0, length, markers + 1)[:k]
    # least squares of x(s) = a1 s + a2 s^2 (x(0) = 0: the axis), the same for y
    A = np.column_stack([s, s * s])
    pinv = np.linalg.pinv(A)  # (2, k)
    dx = pos_m[:, :k, 0] @ pinv[0]
    dy = pos_m[:, :k, 1] @ pinv[0]
    return np.arctan2(dx, -dy)
