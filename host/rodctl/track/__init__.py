"""Ground truth from video: `rodctl track` compares the board's estimate with the rod a camera saw.

    from rodctl.track import track
    result = track("run.mp4", "run.csv", params, markers=8)   # Tracked: angles on the log's clock, errors

One streamed pass over the frames (OpenCV decodes and finds the colored markers) keeps only the
marker centroids; the hub, the scale, each marker's place along the rod, the time alignment and
the comparison are done on those (rodctl.track.shape, .align, .compare).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from rodgains.errors import InputError

from rodctl.track.align import Alignment, align
from rodctl.track.compare import error_table, estimate_at, on_branch, settle_time
from rodctl.track.markers import ColorRange, Detector
from rodctl.track.shape import (FILLED, GOOD, REPEATED, UNUSABLE, base_tangent, edge_angles, find_hub, place, rod_length_px,
                                rod_markers, to_world)
from rodctl.track.video import Video

REPEAT_SHARE = 0.3  # a frame this much more like its predecessor than frames usually are is a repeat
WHOLE_AREA_SHARE = 0.7  # a blob smaller than this share of the median marker is partly hidden
STILL_PX = 1.0  # markers moving less than this per frame: a repeat cannot be told, nor does it matter [px]
MIN_MARKERS_PER_FRAME = 2  # median detections per frame below this: not a video of the rod's markers


@dataclass
class Tracked:
    video: str
    fps: float
    frames: int
    hub_px: np.ndarray
    m_per_px: float
    video_time_s: np.ndarray  # per frame [s]
    time_s: np.ndarray  # per frame, on the telemetry log's clock [s]
    theta: np.ndarray  # (frames, N) tracked edge angles [rad], absolute, 0 hanging
    markers_m: np.ndarray  # (frames, markers + 1, 2) [m], x right, y up, the axis at 0
    quality: np.ndarray  # per frame: rodctl.track.shape GOOD / FILLED / UNUSABLE / REPEATED
    alignment: Alignment
    estimate: np.ndarray  # (frames, N) the log's theta_hat at time_s [rad]
    errors: list[dict] = field(default_factory=list)
    settled_from_s: float | None = None

    def counts(self) -> dict[str, int]:
        return {name: int(np.sum(self.quality == q)) for name, q in
                (("good", GOOD), ("filled", FILLED), ("unusable", UNUSABLE), ("repeated", REPEATED))}


def detect_all(video: Video, detector: Detector, progress: Callable[[int], None] | None = None):
    """(centroids per frame, repeated-frame flags): the one pass over the video.

    A camera that drops a frame often repeats the last one to keep its rate: the repeat has the
    same sensor noise as its original, where a new frame has new noise, so its mean absolute
    difference from the previous frame (on a sparse grid of grey pixels) is a fraction of the others'."""
    import cv2

    dets, diffs = [], []
    prev = None
    for k, frame in enumerate(video):
        dets.append(detector(frame))
        grey = cv2.cvtColor(frame[::4, ::4], cv2.COLOR_BGR2GRAY).astype(np.int16)
        diffs.append(float(np.mean(np.abs(grey - prev))) if prev is not None else np.inf)
        prev = grey
        if progress is not None:
            progress(k + 1)
    diffs = np.asarray(diffs)
    finite = diffs[np.isfinite(diffs)]
    typical = float(np.median(finite)) if finite.size else 0.0
    repeated = diffs < REPEAT_SHARE * typical
    return dets, repeated


def track(video_path: str | Path, log_path: str | Path, params, *, markers: int | None = None,
          color: ColorRange | None = None, hub: tuple[float, float] | None = None, scale: float | None = None,
          view=None, progress: Callable[[int, int], None] | None = None) -> Tracked:
    """Track the video against the telemetry log (see the module doc). params: the rod's parameter
    file (its length, and the design's N). markers: on the rod besides the axis's (default N). view:
    a rodctl.track.calibrate.View (lens and tilt removed, scale from the checkerboard)."""
    from rodctl.logs import read_log
    from rodctl.logs.metadata import counts_per_rev_of, params_of

    log = read_log(log_path)
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

    video = Video(video_path)
    detector = Detector(color or ColorRange.parse(None))
    total = video.frames
    dets, repeated = detect_all(video, detector, (lambda k: progress(k, total)) if progress else None)
    # a marker partly hidden (a finger at its edge) has a shifted centroid: only whole ones count
    areas = np.concatenate([d[:, 2] for d in dets if len(d)]) if any(len(d) for d in dets) else np.zeros(0)
    whole = WHOLE_AREA_SHARE * float(np.median(areas)) if areas.size else 0.0
    dets = [d[d[:, 2] >= whole, :2] for d in dets]
    counts = np.array([len(d) for d in dets])
    if not len(dets) or np.median(counts) < MIN_MARKERS_PER_FRAME:
        raise InputError(f"{video_path}: no markers of the color {detector.lo.tolist()}..{detector.hi.tolist()} "
                         f"(HSV) in most frames (median {np.median(counts) if len(dets) else 0:g} per frame): "
                         "is this a video of the rod? set the markers' color with --color")
    hub_px = np.asarray(hub, float) if hub is not None else find_hub(dets)
    if hub_px is None:
        raise InputError(f"{video_path}: no marker holds still on the motor axis: give the axis with --hub X,Y [px]")
    if scale is not None:
        m_per_px = float(scale)
    else:
        m_per_px = length / rod_length_px(dets, hub_px, markers)
    spacing_px = length / markers / m_per_px

    F = len(dets)
    pos_px = np.full((F, markers + 1, 2), np.nan)
    quality = np.full(F, UNUSABLE, np.int8)
    for k, d in enumerate(dets):
        if repeated[k]:
            quality[k] = REPEATED
            continue
        pos, q = place(rod_markers(d, hub_px), hub_px, markers, spacing_px)
        quality[k] = q
        if q != UNUSABLE:
            pos_px[k] = pos
    # a repeat the frame difference missed (a keyframe re-encodes the noise): the markers stood still
    # between two frames the motion around them says should differ
    for k in range(1, F - 1):
        if quality[k] > FILLED or quality[k - 1] > FILLED or quality[k + 1] > FILLED:
            continue
        moved = np.nanmax(np.hypot(*(pos_px[k] - pos_px[k - 1]).T))
        expected = np.nanmax(np.hypot(*(pos_px[k + 1] - pos_px[k - 1]).T)) / 2
        if expected > STILL_PX and moved < REPEAT_SHARE * expected:
            quality[k] = REPEATED
            pos_px[k] = np.nan
    if view is not None:
        hub_m = view.to_plane(hub_px[None, :])[0]
        flat = pos_px.reshape(-1, 2)
        good = np.isfinite(flat[:, 0])
        plane = np.full_like(flat, np.nan)
        plane[good] = view.to_plane(flat[good]) - hub_m
        markers_m = plane.reshape(pos_px.shape)
        m_per_px = float(np.sqrt(abs(np.linalg.det(view.H[:2, :2]))))  # near the image centre
    else:
        markers_m = to_world(pos_px, hub_px, m_per_px)
    theta = edge_angles(markers_m, length, n_edges)
    ok = quality <= FILLED
    if ok.sum() < 20:
        raise InputError(f"{video_path}: only {ok.sum()} of {F} frames show the rod's markers well enough to track")
    for i in range(n_edges):  # continuous angles across turns
        theta[ok, i] = np.unwrap(theta[ok, i])

    tau = np.arange(F) / video.fps
    t_log = np.asarray(data["time_s"], float)
    th_log = np.asarray(data["encoder_count"], float) * 2 * np.pi / cpr
    base = base_tangent(markers_m, length)
    base[ok] = np.unwrap(base[ok])
    al = align(tau[ok], base[ok], t_log, th_log, video.fps)
    t = al.log_time(tau)
    # the branch (multiple of a turn) of the tracked angles that matches the log's
    turns = np.round((al.angle_offset_rad) / (2 * np.pi))
    theta -= turns * 2 * np.pi

    theta_hat = np.column_stack([np.asarray(data[f"theta_hat_{i + 1}_rad"], float) for i in range(n_edges)])
    est = estimate_at(t, t_log, theta_hat)
    settled = settle_time(t_log, np.asarray(data["mode_code"]))
    tracked = on_branch(np.where(ok[:, None], theta, np.nan), est)
    errors = error_table(t, tracked, est, settled)
    return Tracked(str(video_path), video.fps, F, hub_px, m_per_px, tau, t, tracked, markers_m, quality, al, est,
                   errors, settled)
