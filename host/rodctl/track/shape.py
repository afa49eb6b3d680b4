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
                UNUSABLE: "too few markers", REPEATED: "a repeated frame"}

HUB_TOL_PX = 3.0  # a marker this close to the same place in most frames is the hub's


def static_spots(dets: list[np.ndarray], share: float = 0.8) -> list[tuple[np.ndarray, float]]:
    """The image points [px] where a blob sits in at least `share` of the frames, with that share: the
    axis's marker, and anything else of the markers' colour that does not move (a sticker, a cable tie)."""
    step = max(1, len(dets) // 400)
    sample = [d for d in dets[::step]]
    pts = [(i, p) for i, d in enumerate(sample) for p in d]
    if not pts:
        return []
    frames = np.array([i for i, _ in pts])
    xy = np.array([p for _, p in pts])
    cells = np.floor(xy / HUB_TOL_PX).astype(np.int64)
    keys = cells[:, 0] * 1_000_003 + cells[:, 1]
    found: list[tuple[np.ndarray, float]] = []
    for key in np.unique(keys):
        sel = keys == key
        c = xy[sel].mean(axis=0)
        near = np.linalg.norm(xy - c, axis=1) <= HUB_TOL_PX
        n = len(np.unique(frames[near]))
        spot = xy[near].mean(axis=0)
        if n >= share * len(sample) and all(np.linalg.norm(spot - q) > HUB_TOL_PX for q, _ in found):
            found.append((spot, n / len(sample)))
    return found


def find_hub(dets: list[np.ndarray], share: float = 0.8, spots=None) -> np.ndarray | None:
    """The image point [px] of the axis's marker, or None: a blob that holds still in at least `share` of
    the frames. Of several, the one the rod turns about: its nearest moving blob (the first marker, on the
    shaft) keeps its distance, where from a still object elsewhere the nearest blob comes and goes.
    spots: static_spots(dets, share) when already found."""
    spots = static_spots(dets, share) if spots is None else spots
    if len(spots) <= 1:
        return spots[0][0] if spots else None
    step = max(1, len(dets) // 400)
    still = [c for c, _ in spots]

    def spread(c: np.ndarray) -> float:
        near = []
        for d in dets[::step]:
            for q in still:  # only what moves: the rod's markers
                d = d[np.hypot(*(d - q).T) > 2 * HUB_TOL_PX] if len(d) else d
            if len(d):
                near.append(np.hypot(*(d - c).T).min())
        return float(np.std(near) / np.median(near)) if len(near) >= 3 else np.inf

    spreads = [spread(c) for c, _ in spots]
    if not np.isfinite(min(spreads)):
        raise InputError(f"the rod hardly moves in this video: {len(spots)} of its markers hold still in "
                         f"{100 * share:.0f} % of the frames, so which one is on the motor axis cannot be told from the "
                         "rod turning about it; give the axis with --hub X,Y [px], or film the swing")
    return spots[int(np.argmin(spreads))][0]


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


def rod_markers(frame_dets: np.ndarray, hub: np.ndarray, markers: int | None = None,
                spacing_px: float | None = None) -> np.ndarray:
    """This frame's markers on the rod, ordered from the hub (the hub's own marker left out): with the markers'
    spacing known, the chain that fits it best (spaced_chain), so that something else of the markers' colour
    within the rod's reach is left out; without, each next the nearest."""
    if not len(frame_dets):
        return frame_dets
    away = frame_dets[np.linalg.norm(frame_dets - hub, axis=1) > 2 * HUB_TOL_PX]
    nearest = order_from_hub(away, hub)
    if markers is None or spacing_px is None or len(away) < 2:
        return nearest
    links = np.hypot(*np.diff(np.vstack([hub, nearest]), axis=0).T) / spacing_px
    if len(away) <= markers and np.all(np.abs(links - 1.0) <= EVEN_LINK):
        return nearest  # evenly spaced already: the search would find the same chain
    return spaced_chain(away, hub, markers, spacing_px)


EVEN_LINK = 0.3  # a chain whose every link is within this share of the spacing needs no search [-]
SKIP_COST = 0.25  # a hidden marker costs what a link half a spacing off does [-]
MAX_TURN_COS = 0.0  # a chain never turns back by more than 90 deg from one link to the next


def spaced_chain(points: np.ndarray, hub: np.ndarray, markers: int, spacing_px: float) -> np.ndarray:
    """The chain from the hub through `points` [px] that fits markers spaced spacing_px along the rod best:
    each link one spacing long (two or three across hidden markers), a hidden marker costing SKIP_COST, no link
    turning back on the last. Dynamic programming over (marker index, this point, the previous one); the
    points left out are not on the rod."""
    n = len(points)
    nodes = np.vstack([hub, points])  # node 0 is the hub
    diff = nodes[None, :, :] - nodes[:, None, :]  # diff[a, b] = b - a
    dist = np.hypot(diff[..., 0], diff[..., 1])
    unit = diff / np.maximum(dist, 1e-9)[..., None]
    # allowed[k, j, l]: from node j (reached from k) on to l: the link does not turn back on k->j, and l is
    # neither the hub, nor k, nor j
    allowed = np.einsum("kjc,jlc->kjl", unit, unit) > MAX_TURN_COS
    idx = np.arange(n + 1)
    allowed[:, :, 0] = False
    allowed[idx, :, idx] = False
    allowed[:, idx, idx] = False
    # step[m - 1][j, l]: the link j->l as m spacings, a hidden marker for each beyond one
    step = [((dist - m * spacing_px) / spacing_px) ** 2 + SKIP_COST * (m - 1) for m in (1, 2, 3)]
    inf = np.inf
    # cost[i][k, j]: the best chain whose marker i is node j, reached from node k
    cost = np.full((markers + 1, n + 1, n + 1), inf)
    back = np.full((markers + 1, n + 1, n + 1, 2), -1, np.int64)  # (index, node) of k's state
    for m in (1, 2, 3):
        if m <= markers:
            cost[m, 0, 1:] = step[m - 1][0, 1:]  # the first link, from the hub
    for i in range(1, markers):
        for m in (1, 2, 3):
            i2 = i + m
            if i2 > markers:
                continue
            # total[k, j, l] = cost[i][k, j] + step[j, l] where the link j->l is allowed
            total = np.where(allowed, cost[i][:, :, None] + step[m - 1][None, :, :], inf)
            best_k = np.argmin(total, axis=0)  # [j, l]
            best = np.take_along_axis(total, best_k[None], axis=0)[0]
            better = best < cost[i2]
            cost[i2] = np.where(better, best, cost[i2])
            back[i2][better] = np.stack([np.full_like(best_k, i), best_k], axis=-1)[better]
    # the end: the tip's marker, or an earlier one with the rest hidden
    ends = [(cost[i].min() + SKIP_COST * (markers - i), i) for i in range(1, markers + 1) if np.isfinite(cost[i].min())]
    if not ends:
        return order_from_hub(points, hub)
    _, i = min(ends)
    k, j = np.unravel_index(np.argmin(cost[i]), cost[i].shape)
    chain = []
    used = set()
    while j != 0 and i > 0:
        if j in used:  # a loop through the same point: not a chain
            return order_from_hub(points, hub)
        used.add(j)
        chain.append(j)
        pi, pk = back[i][k, j]
        i, j, k = pi, k, pk
        if i <= 0 or j == 0:
            break
    return nodes[chain[::-1]]


def stray_spots(dets: list[np.ndarray], hub: np.ndarray, markers: int, spacing_px: float,
                spots=None) -> list[np.ndarray]:
    """The still things of the markers' colour that are not on the rod [px]: still spots (static_spots, the
    hub's aside) that the spaced chain leaves out in most of the frames showing them. A marker of a rod held
    balanced for most of the clip holds still too, but the chain runs through it."""
    spots = [c for c, _ in (static_spots(dets) if spots is None else spots) if np.linalg.norm(c - hub) > 2 * HUB_TOL_PX]
    if not spots:
        return []
    seen, used = np.zeros(len(spots)), np.zeros(len(spots))
    for d in dets[::max(1, len(dets) // 400)]:
        if not len(d):
            continue
        chain = rod_markers(d, hub, markers, spacing_px)
        for i, c in enumerate(spots):
            if np.hypot(*(d - c).T).min() <= HUB_TOL_PX:
                seen[i] += 1
                used[i] += bool(len(chain)) and np.hypot(*(chain - c).T).min() <= HUB_TOL_PX
    return [c for c, n, u in zip(spots, seen, used) if n and u < 0.5 * n]


def without_strays(frame_dets: np.ndarray, strays: list[np.ndarray], spacing_px: float) -> np.ndarray:
    """frame_dets without the blobs within half a spacing of a stray spot: a marker passing over one merges
    with it into one blob whose centroid is neither (the markers are less than a spacing across, so a merged
    centroid is within half a spacing of the spot); the marker is then hidden, and filled in."""
    for c in strays:
        if len(frame_dets):
            frame_dets = frame_dets[np.hypot(*(frame_dets - c).T) > 0.5 * spacing_px]
    return frame_dets


def chain_length(ordered: np.ndarray, hub: np.ndarray) -> float:
    pts = np.vstack([hub, ordered])
    return float(np.sum(np.hypot(*np.diff(pts, axis=0).T)))


def rod_length_px(dets: list[np.ndarray], hub: np.ndarray, markers: int, spots=None) -> float:
    """The rod's length in the image [px]: the median chain length of the frames showing every marker."""
    step = max(1, len(dets) // 2000)
    still = [c for c, _ in (static_spots(dets) if spots is None else spots) if np.linalg.norm(c - hub) > 2 * HUB_TOL_PX]

    def lengths_without(still: list) -> list[float]:
        out = []
        for d in dets[::step]:
            for c in still:  # something else that holds still is not a marker the rod carries past it
                d = d[np.hypot(*(d - c).T) > HUB_TOL_PX] if len(d) else d
            m = rod_markers(d, hub)
            if len(m) == markers:
                out.append(chain_length(m, hub))
        return out
    lengths = lengths_without(still)
    if len(lengths) < 3 and still:  # a rod that hangs still most of the clip: its own markers are the still spots
        lengths = lengths_without([])
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


def rotate(markers_m: np.ndarray, angle_rad: float) -> np.ndarray:
    """The markers [m] turned counter-clockwise by angle_rad about the axis: every edge angle grows by it."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    out = np.empty_like(markers_m)
    out[..., 0] = c * markers_m[..., 0] - s * markers_m[..., 1]
    out[..., 1] = s * markers_m[..., 0] + c * markers_m[..., 1]
    return out
