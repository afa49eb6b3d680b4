"""Ground truth from video: `rodctl track` compares the board's estimate with the rod a camera saw.

    from rodctl.track import track
    result = track("run.mp4", "run.csv", params, markers=8)   # Tracked: angles on the log's clock, errors

One streamed pass over the frames (OpenCV decodes and finds the colored markers) keeps only the
marker centroids; the hub, the scale, each marker's place along the rod, the time alignment and
the comparison are done on those (rodctl.track.shape, .align, .compare).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from rodgains.errors import InputError, UserError

from rodctl.track.align import SLOWDOWNS, Alignment, align
from rodctl.track.compare import error_table, estimate_at, on_branch, settle_time
from rodctl.track.markers import ColorRange, Detector
from rodctl.track.rest_shape import RestShape, RestShapeError, measure_rest_shape, summary
from rodctl.track.shape import (FILLED, GOOD, REPEATED, UNUSABLE, base_tangent, edge_angles, find_hub, place,
                                rod_length_px, rod_markers, rotate, static_spots, stray_spots, to_world, without_strays)
from rodctl.track.video import Video

REPEAT_SHARE = 0.3  # markers moving less than this share of the step the motion around them predicts: a repeat
STILL_PX = 1.0  # markers moving less than this per frame: a repeat cannot be told, nor does it matter [px]
SAME_STILL_PX = 0.2  # the same, for a frame whose picture is its predecessor's [px]
SAME_MOVED_SHARE = 0.5  # and REPEAT_SHARE for it: the picture already says it is one [-]
SAME_GREY = 3  # a repeat decoded again differs from its original by less than this, or 3 noise sigmas [grey levels]
SAME_SHARE = 1e-3  # share of the pixels a repeat may have beyond that [-]
WHOLE_AREA_SHARE = 0.7  # a blob smaller than this share of the median marker is partly hidden
MERGED_AREA_SHARE = 1.7  # a blob this much larger than the median marker is two run together (or not a marker)
REACH_SHARE = 1.2  # a blob farther from the axis than this share of the rod's length is not on the rod
MIN_MARKERS_PER_FRAME = 2  # median detections per frame below this: not a video of the rod's markers
MAX_FILMED_FPS = 100_000.0  # a high-speed camera's rate at most [1/s]
COVERED_WARN = 0.95  # a log covering less of the video's usable frames than this is said to [-]


@dataclass
class Tracked:
    video: str
    fps: float  # the rate the video was filmed at (a slow-motion file's times its slowdown) [1/s]
    frames: int
    hub_px: np.ndarray
    m_per_px: float
    video_time_s: np.ndarray  # per frame [s]
    time_s: np.ndarray  # per frame, on the telemetry log's clock [s]
    theta: np.ndarray  # (frames, N) tracked edge angles [rad], absolute, 0 hanging
    markers_m: np.ndarray  # (frames, markers + 1, 2) [m], x right, y up (level), the axis at 0
    quality: np.ndarray  # per frame: rodctl.track.shape GOOD / FILLED / UNUSABLE / REPEATED
    alignment: Alignment
    estimate: np.ndarray  # (frames, N) the log's theta_hat at time_s [rad]
    errors: list[dict] = field(default_factory=list)
    settled_from_s: float | None = None
    roll_removed_rad: float = 0.0  # taken off every angle: the camera's roll, without a calibration [rad]
    warnings: list[str] = field(default_factory=list)  # one line each, printed on stderr by track()
    # the rod's curvature at rest from the frames it hangs still (rodctl.track.rest_shape); None: not measured
    rest_shape: RestShape | None = None
    rest_note: str = ""  # one line: what to put in the parameter file, or why it was not measured

    def counts(self) -> dict[str, int]:
        return {name: int(np.sum(self.quality == q)) for name, q in
                (("good", GOOD), ("filled", FILLED), ("unusable", UNUSABLE), ("repeated", REPEATED))}


def detect_all(video: Video, detector: Detector, progress: Callable[[int], None] | None = None):
    """(centroids per frame, same-picture flags): the one pass over the video.

    same[k]: frame k shows frame k - 1's picture again, pixel for pixel, to within the decoder's
    rounding or the frame's own noise (a camera that drops a frame may repeat the last one). Not a
    brightness statistic: flickering light or a noise-free camera make ordinary frames differ more or
    less from their predecessors, a repeat is the same picture. A repeat re-encoded as a keyframe is
    not the same picture; the markers standing still tell those (flag_repeats)."""
    import cv2

    dets, same = [], []
    prev = None
    for k, frame in enumerate(video):
        dets.append(detector(frame))
        grey = cv2.cvtColor(frame[::4, ::4], cv2.COLOR_BGR2GRAY).astype(np.int16)
        same.append(prev is not None and _same_picture(grey, prev))
        prev = grey
        if progress is not None:
            progress(k + 1)
    return dets, np.asarray(same, bool)


def _same_picture(grey: np.ndarray, prev: np.ndarray) -> bool:
    """Two grey images [levels] are one picture: at most SAME_SHARE of their pixels differ by more than
    SAME_GREY or 3 sigmas of the image's own noise (from neighbouring pixels' differences)."""
    diff = np.abs(grey - prev)
    if np.mean(diff > SAME_GREY) <= SAME_SHARE:
        return True
    sub = grey[::4]  # the noise only when the plain test fails: most frames of a real camera
    sigma = float(np.median(np.abs(np.diff(sub, axis=1)))) / 0.954  # median |N(0, 2 s^2)| = 0.954 s
    return 3 * sigma > SAME_GREY and np.mean(diff > 3 * sigma) <= SAME_SHARE


def motion_test(pos_px: np.ndarray, usable: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(off_path [px], moved [px], judged) per frame, from the markers [px] (frames, markers + 1, 2).

    The cubic through frames k-2, k-1, k+1, k+2 predicts frame k: off_path is how far the markers
    stand from that prediction, moved how far from frame k-1's. A repeat sits on frame k-1's positions,
    a step of the motion off the prediction; an ordinary frame the other way round. Three frames
    would not do: at the end of a swing the rod turns, and a frame next to the turn stands still
    between two that differ. judged: the five frames all show the rod."""
    F = len(pos_px)
    off_path, moved, judged = np.zeros(F), np.zeros(F), np.zeros(F, bool)
    if F < 5:
        return off_path, moved, judged
    k = np.arange(2, F - 2)
    judged[k] = usable[k - 2] & usable[k - 1] & usable[k] & usable[k + 1] & usable[k + 2]
    pred = 2 / 3 * (pos_px[k - 1] + pos_px[k + 1]) - 1 / 6 * (pos_px[k - 2] + pos_px[k + 2])
    off_path[k] = _max_px(pos_px[k] - pred)
    moved[k] = _max_px(pos_px[k] - pos_px[k - 1])
    return off_path, moved, judged


def _max_px(d: np.ndarray) -> np.ndarray:
    """Per frame, the largest marker displacement [px] of (frames, markers + 1, 2)."""
    n = np.hypot(d[..., 0], d[..., 1])
    return np.max(np.where(np.isfinite(n), n, 0.0), axis=1)


def whole_markers(dets: list[np.ndarray]) -> tuple[list[np.ndarray], np.ndarray]:
    """(centroids [px] of the blobs of a marker's usual size, per frame whether a larger blob was left out). A marker
    partly hidden (a finger at its edge) has a shifted centroid; two markers run together (or something pink) are
    one blob of about twice the area, with its centroid between them: both are left out, as not seen. So is a marker
    smeared by motion blur, which a frame's `large` tells."""
    areas = np.concatenate([d[:, 2] for d in dets if len(d)]) if any(len(d) for d in dets) else np.zeros(0)
    typical = float(np.median(areas)) if areas.size else 0.0
    lo, hi = WHOLE_AREA_SHARE * typical, MERGED_AREA_SHARE * typical
    large = np.array([bool(len(d)) and bool(np.any(d[:, 2] > hi)) for d in dets], bool)
    return [d[(d[:, 2] >= lo) & (d[:, 2] <= hi), :2] for d in dets], large


def within_reach(dets: list[np.ndarray], hub_px: np.ndarray, reach_px: float) -> list[np.ndarray]:
    """Each frame's blobs no farther than reach_px [px] from the axis: beyond the rod's length they
    are something else of the markers' color, and would lengthen the chain of markers."""
    return [d[np.hypot(*(d - hub_px).T) <= reach_px] if len(d) else d for d in dets]


def place_all(dets: list[np.ndarray], hub_px: np.ndarray, markers: int, spacing_px: float, spots=None):
    """(positions [px] (frames, markers + 1, 2), NaN where not seen; quality per frame)."""
    F = len(dets)
    pos_px = np.full((F, markers + 1, 2), np.nan)
    quality = np.full(F, UNUSABLE, np.int8)
    strays = stray_spots(dets, hub_px, markers, spacing_px, spots)
    for k, d in enumerate(dets):
        d = without_strays(d, strays, spacing_px)
        pos, q = place(rod_markers(d, hub_px, markers, spacing_px), hub_px, markers, spacing_px)
        quality[k] = q
        if q != UNUSABLE:
            pos_px[k] = pos
    return pos_px, quality


def flag_repeats(pos_px: np.ndarray, quality: np.ndarray, same: np.ndarray) -> None:
    """Mark the repeated frames REPEATED and forget their markers (in place).

    Where the markers can judge (motion_test), a repeat is a frame whose markers stood still while the
    motion around them says they should have moved on: by over STILL_PX, or, when the picture is
    also its predecessor's (detect_all), by over SAME_STILL_PX (a slow swing). A frame whose markers
    moved less than that is no repeat one can tell, nor does it matter. Where the markers cannot
    judge (the rod not seen around it), the picture alone decides."""
    usable = quality <= FILLED
    off_path, moved, judged = motion_test(pos_px, usable)
    stalled = judged & (off_path > STILL_PX) & (moved < REPEAT_SHARE * off_path)
    stalled |= judged & same & (off_path > SAME_STILL_PX) & (moved < SAME_MOVED_SHARE * off_path)
    _one_of_a_pair(stalled, moved)
    repeated = np.where(judged, stalled, same & ~_still_around(pos_px, usable))
    quality[repeated] = REPEATED
    pos_px[repeated] = np.nan


def _still_around(pos_px: np.ndarray, usable: np.ndarray) -> np.ndarray:
    """Per frame: the markers stood still (under STILL_PX) from the frame before through the frame after, all three
    seen. A rod hanging still at a clip's ends, where the motion test cannot judge, shows the same picture twice
    without any frame being dropped (it was called a repeat); a dropped frame amid motion has a step beside it."""
    F = len(pos_px)
    out = np.zeros(F, bool)
    if F < 3:
        return out
    step = np.full(F, np.inf)  # step[k]: from frame k - 1 to k [px]
    both = usable[1:] & usable[:-1]
    step[1:][both] = _max_px(pos_px[1:][both] - pos_px[:-1][both])
    out[1:-1] = (step[1:-1] < STILL_PX) & (step[2:] < STILL_PX)
    out[-1] = step[-1] < STILL_PX and step[-2] < STILL_PX  # the last frame has no frame after it: the two before
    return out


def _one_of_a_pair(stalled: np.ndarray, moved: np.ndarray) -> None:
    """A repeat spoils its neighbours' predictions too: next to a turn of the swing (a frame that hardly
    moves) both look stalled; the repeat is the one that did not move at all (in place)."""
    pair = np.flatnonzero(stalled[:-1] & stalled[1:])
    stalled[np.where(moved[pair] <= moved[pair + 1], pair + 1, pair)] = False


def to_plane(pos_px: np.ndarray, hub_px: np.ndarray, view) -> tuple[np.ndarray, float]:
    """(markers [m] in the rod's plane, the axis at 0; metres per pixel near the image centre)."""
    hub_m = view.to_plane(hub_px[None, :])[0]
    flat = pos_px.reshape(-1, 2)
    good = np.isfinite(flat[:, 0])
    plane = np.full_like(flat, np.nan)
    plane[good] = view.to_plane(flat[good]) - hub_m
    return plane.reshape(pos_px.shape), float(np.sqrt(abs(np.linalg.det(view.H[:2, :2]))))


def _print_warning(text: str) -> None:
    print(f"rodctl: warning: {text}", file=sys.stderr)


def track(video_path: str | Path, log_path: str | Path, params, *, markers: int | None = None,
          color: ColorRange | None = None, hub: tuple[float, float] | None = None, scale: float | None = None,
          view=None, filmed_fps: float | None = None, progress: Callable[[int, int], None] | None = None,
          warn: Callable[[str], None] | None = _print_warning, say: Callable[[str], None] | None = print) -> Tracked:
    """Track the video against the telemetry log (see the module doc). params: the rod's parameter
    file (its length, and the design's N). markers: on the rod besides the axis's (default N). view:
    a rodctl.track.calibrate.View (lens and tilt removed, scale and level from the checkerboard).
    filmed_fps: the rate the video was filmed at [1/s] (default: found, the file's or a slow-motion
    factor of it, rodctl.track.align.SLOWDOWNS).
    Without a view the camera's roll is the constant angle the alignment measures between the
    camera's base angle and the encoder's, and is taken off every angle (Tracked.roll_removed_rad).
    warn, say: called with each warning (default: stderr) and note (default: stdout), one line each,
    once the tracking has succeeded (a refused video gets its one line of error, nothing else)."""
    from rodctl.logs import read_log
    from rodctl.logs.metadata import counts_per_rev_of, params_of

    log = read_log(log_path, columns=["time_s", "mode_code", "encoder_count", "theta_hat_*"])  # what it compares
    data = log.data
    if data.size < 2:
        raise InputError(f"{log_path}: no telemetry to align the video with")
    lp = params_of(log.meta)
    p = params if params is not None else lp
    length = float(p["rod"]["length"])
    n_edges = sum(1 for c in data.dtype.names if c.startswith("theta_hat_"))
    markers = int(markers or n_edges)
    if not 2 <= markers <= 64:
        raise InputError(f"--markers {markers}: between 2 and 64 markers on the rod")
    cpr = counts_per_rev_of(log.meta, lp if lp is not None else p)
    warnings: list[str] = []

    if filmed_fps is not None and not 0 < filmed_fps <= MAX_FILMED_FPS:
        raise InputError(f"--fps {filmed_fps:g}: the rate the video was filmed at, above 0 and up to "
                         f"{MAX_FILMED_FPS:g} frames per second")
    video = Video(video_path)
    if hub is not None and not (0 <= hub[0] < video.width and 0 <= hub[1] < video.height):
        raise InputError(f"--hub {hub[0]:g},{hub[1]:g}: outside the video's {video.width}x{video.height} px image")
    detector = Detector(color or ColorRange.parse(None))
    total = video.frames
    dets, same = detect_all(video, detector, (lambda k: progress(k, total)) if progress else None)
    dets, large = whole_markers(dets)
    counts = np.array([len(d) for d in dets])
    if not len(dets) or np.median(counts) < MIN_MARKERS_PER_FRAME:
        raise InputError(f"{video_path}: no markers of the color {list(detector.color.lo)}..{list(detector.color.hi)} "
                         f"(HSV) in most frames (median {np.median(counts) if len(dets) else 0:g} per frame): "
                         "is this a video of the rod? set the markers' color with --color")
    spots = static_spots(dets)
    hub_px = np.asarray(hub, float) if hub is not None else find_hub(dets, spots=spots)
    if hub_px is None:
        raise InputError(f"{video_path}: no marker holds still on the motor axis: give the axis with --hub X,Y [px]")
    length_px = length / float(scale) if scale is not None else rod_length_px(dets, hub_px, markers, spots)
    m_per_px = length / length_px
    dets = within_reach(dets, hub_px, REACH_SHARE * length_px)
    spacing_px = length_px / markers

    F = len(dets)
    pos_px, quality = place_all(dets, hub_px, markers, spacing_px, spots)
    flag_repeats(pos_px, quality, same)
    if view is not None:
        markers_m, m_per_px = to_plane(pos_px, hub_px, view)
    else:
        markers_m = to_world(pos_px, hub_px, m_per_px)
    ok = quality <= FILLED
    smeared = int(np.count_nonzero(large & (quality == UNUSABLE)))
    if smeared >= max(3, 0.01 * F):
        warnings.append(f"{smeared} of the {int(np.count_nonzero(quality == UNUSABLE))} frames with too few markers lost a marker to a "
                        f"blob more than {MERGED_AREA_SHARE:g} x a marker's area: motion blur at the swing's fastest "
                        "(film with a shorter exposure, 1/1000 s or less), or markers run together")
    if ok.sum() < 20:
        raise InputError(f"{video_path}: only {ok.sum()} of {F} frames show the rod's markers well enough to track")

    tau, uneven = video.frame_times(F)
    if uneven:
        warnings.append(uneven)
    t_log = np.asarray(data["time_s"], float)
    th_log = np.asarray(data["encoder_count"], float) * 2 * np.pi / cpr
    base = base_tangent(markers_m, length)
    base[ok] = np.unwrap(base[ok])
    slowdowns = (filmed_fps / video.fps,) if filmed_fps is not None else SLOWDOWNS
    play = p["gearbox"]["backlash_deg"] if p["encoder"]["location"] == "motor" else 0.0
    al = align(tau[ok], base[ok], t_log, th_log, video.fps, slowdowns, play_deg=play)
    drift_warning = al.drift_warning()
    if drift_warning:
        warnings.append(drift_warning)
    if al.covered < COVERED_WARN:
        warnings.append(f"the log covers {100 * al.covered:.0f} % of the video's usable frames ({al.covered_s:.1f} s): "
                        "only those are compared, and the clock drift is measured over them (a log cut short, or "
                        "filming started before logging?)")
    t = al.log_time(tau)
    c = al.angle_offset_rad
    if al.mirrored:  # the rod seen from behind its plane: x about the axis turned back
        markers_m = markers_m * np.array([-1.0, 1.0])
    # without a board nothing in the picture is level: the camera's roll is the constant the
    # alignment measured (less whole turns); with one, the board's rows are level
    roll = float(c - np.round(c / (2 * np.pi)) * 2 * np.pi) if view is None else 0.0
    markers_m = rotate(markers_m, -roll)
    theta = edge_angles(markers_m, length, n_edges)
    for i in range(n_edges):  # continuous angles across turns
        theta[ok, i] = np.unwrap(theta[ok, i])
    # the branch (multiple of a turn) of the tracked angles that matches the log's
    theta -= np.round((c - roll) / (2 * np.pi)) * 2 * np.pi

    theta_hat = np.column_stack([np.asarray(data[f"theta_hat_{i + 1}_rad"], float) for i in range(n_edges)])
    est = estimate_at(t, t_log, theta_hat)
    settled = settle_time(t_log, np.asarray(data["mode_code"]))
    tracked = on_branch(np.where(ok[:, None], theta, np.nan), est)
    errors = error_table(t, tracked, est, settled)
    # GOOD frames alone: a marker filled in from its neighbours is a spline's guess, and the curvature is the
    # markers' departure from a rigid motion by a millimetre
    try:
        rest = measure_rest_shape(t, markers_m, quality == GOOD, t_log, np.asarray(data["mode_code"]),
                                  np.asarray(data["encoder_count"]), p, cpr)
        rest_note = summary(rest)
    except (RestShapeError, UserError) as e:  # the file cannot make the plant's rod: the tracking still stands
        rest = None
        rest_note = f"rest curvature not measured: the hanging rod's model did not fit the still frames ({e})"
    if al.slowdown != 1.0 and filmed_fps is None and say is not None:
        say(f"slow motion: the file plays at {video.fps:g} fps, {al.slowdown:g} x slower than it was filmed "
            f"({video.fps * al.slowdown:g} fps); --fps gives the rate filmed")
    if al.mirrored and say is not None:
        say("mirrored: the rod turns against the encoder in the picture (filmed from behind the rod's plane, or a "
            "mirrored camera): its x is turned back about the axis")
    if view is None and say is not None:
        say(f"level: no --calibrate, so the camera's roll is taken to be the alignment's camera minus encoder "
            f"({np.degrees(roll):+.2f} deg) and is removed from every angle")
    # Only a measurement is said: most videos have no still lead-in, and for a straight rod that needs no
    # note each time; why it was not measured is Tracked.rest_note, which rodctl track prints
    if rest is not None and say is not None:
        say(rest_note)
    if warn is not None:
        for w in warnings:
            warn(w)
    return Tracked(str(video_path), video.fps * al.slowdown, F, hub_px, m_per_px, tau, t, tracked, markers_m, quality,
                   al, est, errors, settled, roll, warnings, rest, rest_note)
