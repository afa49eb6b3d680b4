"""The rod's curvature at rest (rod.rest_curvature [1/m]), measured from the frames where it hangs still.

    rest = measure_rest_shape(t_s, markers_m, usable, t_log, mode, count, params, cpr)  # RestShape or None

A rod curved at rest needs its curvature in the parameter file, with the right sign: the design then holds its
straightest shape upright (docs/control.md, "A rod curved at rest"); on the matrix's 0.82 1/m rod the wrong sign
costs 16.9 deg of lean. The
curvature is defined on the rod hanging at rest with its hub vertical, positive when the hanging tip is offset
toward increasing encoder angles. The video, once aligned with the log (mirror and roll taken off by
rodctl.track), already sees the rod in the encoder's sense, so the sign comes with the measurement.

The still frames: the log DISARMED with the encoder's count unchanged, and the markers holding still (STILL_SHARE),
for at least MIN_STILL_S in a row; the longest such stretch is used. Its markers' mean positions are fitted with
the faithful plant's hanging rod (rodctl.sim.statics.hanging_nodes, its own weight straightening it) at the
markers' arc lengths, over the curvature and a rigid motion in the rod's plane (Gauss-Newton, the curvature's
derivative by differences: the shape is nearly linear in it).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from rodctl.track.shape import rotate

MODE_DISARMED = 0  # the log's mode_code with the driver off (rodctl.logs.schema)
# A still rod whose encoder is farther than this from hanging (less whole turns) is not hanging but resting on
# something (a stop, a hand): not the shape the model is of, and near upright it has none [deg]
HANGING_DEG = 30.0
# A stretch this long at least [s]: 36 frames at 120 fps, whose mean takes each centroid's frame-to-frame noise
# (0.16 px at most on the tests' clips) well under the curvature's own mark on the markers, about 1 mm at the
# matrix's 0.82 1/m once a rigid motion is taken out; and a swing's turning point, or a rod a hand holds for a
# moment, is not taken for a rod hanging at rest.
MIN_STILL_S = 0.3
# Still: every marker within this share of the rod's length of its mean over MIN_STILL_S around the frame [-].
# 1.6 mm on the 155 mm rod: 2.5 px where the rod is the 250 px long the camera must at least see it
# (docs/howto/film-a-run.md), above the centroids' noise (the largest marker's deviation in a still frame of
# the tests' clips: 0.6 px); a rod swaying by less biases the mean shape by a fraction of that (a sway's mean is
# the rest shape), and a rod still swinging by a degree (its tip 2.7 mm) is not still.
STILL_SHARE = 0.01
KAPPA_STEP_PER_M = 0.05  # the difference step of the shape's derivative in the curvature [1/m]
MAX_KAPPA_PER_M = 20.0  # the parameter file's own limit (a radius of 5 cm): the fit stops there [1/m]
FIT_ITERATIONS = 12
CONVERGED_PER_M = 1e-5  # a curvature step smaller than this ends the fit [1/m]
# A fit whose markers sit farther than this from the measured ones, RMS, is not the hanging rod's shape (a hand
# on it, a marker mistaken): said as not measured rather than put in a file where the wrong sign costs 16.9 deg
# on the matrix's rod. The tests' fits: 0.12 to 0.13 mm; the matrix's curvature moves the markers about 1 mm [m].
MAX_RESIDUAL_M = 0.4e-3


class RestShape(NamedTuple):
    """The rod's curvature at rest as the still frames show it."""

    kappa_per_m: float  # rod.rest_curvature: positive when the hanging tip is toward increasing angles [1/m]
    tip_offset_m: float  # the tip's offset from the vertical hanging at rest, the hub vertical, at that curvature [m]
    still_from_s: float  # the still stretch's first frame, on the log's clock [s]
    still_to_s: float  # and its last [s]
    frames: int  # frames averaged
    rms_residual_m: float  # the fitted model's markers from the measured mean ones, RMS distance [m]


class RestShapeError(ArithmeticError):
    """The still frames are there but no rest curvature fits them (the model's statics did not converge)."""


def still_stretch(t_s: np.ndarray, markers_m: np.ndarray, usable: np.ndarray, t_log: np.ndarray,
                  mode: np.ndarray, count: np.ndarray, length_m: float, counts_per_rev: float) -> np.ndarray | None:
    """The frame indices of the longest still stretch lasting MIN_STILL_S [s] or more, or None.

    t_s: each frame's time on the log's clock [s]; markers_m: (frames, markers + 1, 2) [m], the axis first;
    usable: the frames whose markers are all known; t_log [s], mode (mode_code), count (encoder_count): the log's;
    length_m: the rod's length [m]; counts_per_rev: the encoder's counts per output turn. A frame that is not
    usable ends a stretch: the rod may have moved unseen."""
    t_s = np.asarray(t_s, float)
    if len(t_log) < 2:
        return None
    run = _log_still_runs(np.asarray(mode), np.asarray(count), counts_per_rev)
    # the log sample at or before each frame, and the next: both in one still run, or the frame is not still
    i = np.searchsorted(t_log, t_s, side="right") - 1
    inside = (i >= 0) & (i < len(t_log) - 1)
    i = np.clip(i, 0, len(t_log) - 2)
    frame_run = np.where(inside & (run[i] >= 0) & (run[i] == run[i + 1]), run[i], -1)
    frame_run = np.where(usable, frame_run, -1)

    best, best_s = None, -1.0
    for a, b in _runs(frame_run):  # frames [a, b) of one log run, every one usable
        if t_s[b - 1] - t_s[a] < MIN_STILL_S:  # an encoder's count flickering at rest: many short runs
            continue
        still = _holds_still(t_s[a:b], markers_m[a:b], STILL_SHARE * length_m)
        for c, d in _runs(np.where(still, 0, -1)):
            span = float(t_s[a + d - 1] - t_s[a + c])
            if span >= MIN_STILL_S and span > best_s:
                best, best_s = np.arange(a + c, a + d), span
    return best


def _log_still_runs(mode: np.ndarray, count: np.ndarray, counts_per_rev: float) -> np.ndarray:
    """Per log sample, a label shared by the consecutive samples DISARMED with one encoder count within HANGING_DEG
    of hanging; -1 elsewhere."""
    disarmed = (mode == MODE_DISARMED) & (np.abs(_hub_deg(count, counts_per_rev)) <= HANGING_DEG)
    new = np.ones(len(mode), bool)
    new[1:] = (count[1:] != count[:-1]) | ~disarmed[:-1]
    label = np.cumsum(new) - 1
    return np.where(disarmed, label, -1)


def _hub_deg(count: np.ndarray, counts_per_rev: float) -> np.ndarray:
    """The encoder's angle [deg] from hanging (its zero, taken hanging at power-on), less whole turns."""
    turn = np.asarray(count, float) / float(counts_per_rev) * 360.0
    return turn - 360.0 * np.round(turn / 360.0)


def _runs(label: np.ndarray):
    """(start, stop) of each maximal run of equal labels other than -1."""
    edges = np.flatnonzero(np.diff(label) != 0) + 1
    starts = np.concatenate([[0], edges])
    stops = np.concatenate([edges, [len(label)]])
    return [(int(a), int(b)) for a, b in zip(starts, stops) if len(label) and label[a] != -1]


def _holds_still(t_s: np.ndarray, markers_m: np.ndarray, tol_m: float) -> np.ndarray:
    """Per frame: every marker within tol_m [m] of its mean over the frames within MIN_STILL_S / 2 [s] of it.
    Running sums: a whole video hanging still costs one pass."""
    pts = markers_m.reshape(len(t_s), -1)
    csum = np.vstack([np.zeros(pts.shape[1]), np.cumsum(pts, axis=0)])
    lo = np.searchsorted(t_s, t_s - MIN_STILL_S / 2, side="left")
    hi = np.searchsorted(t_s, t_s + MIN_STILL_S / 2, side="right")
    mean = (csum[hi] - csum[lo]) / (hi - lo)[:, None]
    d = (pts - mean).reshape(markers_m.shape)
    return np.max(np.hypot(d[..., 0], d[..., 1]), axis=1) <= tol_m


class _Model:
    """The faithful plant's hanging rod's marker points [m] (markers, 2), axis left out, for a rest curvature."""

    def __init__(self, params, markers: int, hub_deg: float):
        from rodctl.sim.plant import faithful_plant

        self.params, self.hub_deg = params, float(hub_deg)
        # the markers are at arc lengths along the rod's material, not along its (slightly stretched) nodes
        self.s_nodes = faithful_plant(params, input_mode="torque", gear=None, coulomb=0.0, at_rest=False).node_arc()
        self.s_m = np.linspace(0.0, float(params["rod"]["length"]), markers + 1)[1:]

    def __call__(self, kappa_per_m: float) -> np.ndarray:
        from rodctl.sim.statics import hanging_nodes
        from rodctl.track.render import points_at

        return points_at(hanging_nodes(_with_kappa(self.params, kappa_per_m), self.hub_deg), self.s_nodes, self.s_m)


def _with_kappa(params, kappa_per_m: float):
    """The parameter file with its rod's rest curvature [1/m] replaced."""
    return params.with_overrides(f"rod.rest_curvature={float(kappa_per_m)!r}")


def fit_rest_curvature(mean_m: np.ndarray, params, hub_deg: float = 0.0) -> tuple[float, np.ndarray, float]:
    """(curvature [1/m], rigid motion (rotation [rad], x [m], y [m]), RMS residual [m]) of the hanging rod whose
    markers best match mean_m ((markers, 2) [m] from the axis, the axis's own left out, at arc lengths i L /
    markers, i = 1 .. markers), its hub held hub_deg [deg] from vertical; the model is turned about the axis,
    then moved.

    The rotation takes what the alignment left of the camera's roll and the hub's place in the gearbox's play:
    the two are not told apart here. Not quite a rotation, a hub tilted in the play bends the hanging rod back
    toward vertical, and that bend reads as curvature: -0.11 1/m per degree of tilt on the matrix's rod.
    The move: the axis is where the still marker on it is seen, and that marker is seen off by a fraction of a
    pixel from the rod's (a dot on a dark screw head, not on the rod: the codec's colour bleeds differently; a
    dot a little off the axis). On the tests' MP4 files the rod's markers sat 0.2 to 0.4 px to one side of it:
    with the axis held, the rod 500 px long, every curvature read 0.035 1/m low; with the move free, within
    0.02. The price: noise that differs from marker to marker moves the curvature 1.6 times as much."""
    model = _Model(params, len(mean_m), hub_deg)
    target = np.asarray(mean_m, float)
    kappa, motion = 0.0, np.zeros(3)
    m = model(kappa)
    across = np.tile([1.0, 0.0], len(target))
    along = np.tile([0.0, 1.0], len(target))
    converged = False
    for _ in range(FIT_ITERATIONS):
        h = -KAPPA_STEP_PER_M if kappa > 0 else KAPPA_STEP_PER_M  # toward 0: within the file's limit
        dm = (model(kappa + h) - m) / h
        p = rotate(m, motion[0])
        r = (p + motion[1:] - target).ravel()
        J = np.column_stack([rotate(dm, motion[0]).ravel(), np.column_stack([-p[:, 1], p[:, 0]]).ravel(),
                             across, along])
        step = np.linalg.lstsq(J, -r, rcond=None)[0]
        new = float(np.clip(kappa + step[0], -MAX_KAPPA_PER_M, MAX_KAPPA_PER_M))
        converged = abs(new - kappa) < CONVERGED_PER_M
        kappa, motion = new, motion + step[1:]
        m = model(kappa)
        if converged:
            break
    if not converged or abs(kappa) >= MAX_KAPPA_PER_M:
        raise RestShapeError(f"the fit did not settle on a curvature within {MAX_KAPPA_PER_M:g} 1/m")
    res = rotate(m, motion[0]) + motion[1:] - target
    return kappa, motion, float(np.sqrt(np.mean(np.sum(res ** 2, axis=1))))


def measure_rest_shape(t_s: np.ndarray, markers_m: np.ndarray, usable: np.ndarray, t_log: np.ndarray,
                       mode: np.ndarray, count: np.ndarray, params, counts_per_rev: float) -> RestShape | None:
    """The rest curvature from the longest still stretch (still_stretch; arguments as there, params the rod's
    parameter file, counts_per_rev the encoder's counts per output turn [1/rev]); None when there is none.
    RestShapeError when the model's statics do not converge for the curvature the fit asks.

    The longest stretch alone, not every still frame: the rod also hangs still after a run, its hub wherever the
    motor stopped and its place in the play another, and the mean of two tilts is neither's shape. The model's
    hub is where the encoder was (0 is vertical: its zero is taken hanging at power-on)."""
    from rodctl.sim.statics import hanging_tip_offset_m

    length = float(params["rod"]["length"])
    frames = still_stretch(t_s, markers_m, usable, t_log, mode, count, length, counts_per_rev)
    if frames is None:
        return None
    k = int(np.searchsorted(t_log, t_s[frames[0]], side="right") - 1)
    hub_deg = float(_hub_deg(count[k], counts_per_rev))
    mean = np.mean(markers_m[frames, 1:, :], axis=0)
    try:
        kappa, _, rms = fit_rest_curvature(mean, params, hub_deg)
        tip = hanging_tip_offset_m(_with_kappa(params, kappa))
    except ArithmeticError as e:
        raise RestShapeError(str(e)) from None
    if rms > MAX_RESIDUAL_M:
        raise RestShapeError(f"its markers are {rms * 1e3:.2f} mm RMS from the hanging rod's best shape, more than "
                             f"{MAX_RESIDUAL_M * 1e3:g} mm")
    return RestShape(kappa, tip, float(t_s[frames[0]]), float(t_s[frames[-1]]), len(frames), rms)


def summary(rest: RestShape | None) -> str:
    """The one line rodctl track says of it (Tracked.rest_note)."""
    if rest is None:
        return (f"rest curvature not measured: no {MIN_STILL_S:g} s in the video with the rod hanging still (the log "
                "DISARMED, the encoder and the markers still); film the rod hanging still for a second before "
                "arming to measure rod.rest_curvature (docs/howto/film-a-run.md)")
    side = "increasing" if rest.tip_offset_m >= 0 else "decreasing"
    return (f"at rest (hanging still {rest.still_from_s:.2f} to {rest.still_to_s:.2f} s, {rest.frames} frames, fit "
            f"residual {rest.rms_residual_m * 1e3:.2f} mm RMS): rest curvature {rest.kappa_per_m:+.2f} 1/m, the "
            f"hanging tip {abs(rest.tip_offset_m) * 1e3:.1f} mm toward {side} angles: rod.rest_curvature in the "
            'parameter file (docs/control.md "A rod curved at rest")')
