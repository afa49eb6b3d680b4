"""Videos of a simulated rod with markers, for the tracker's tests, its benchmark and its docs.

    frames = RodScene(width=640, height=480, ...).render(nodes_m, t_s)   # one BGR frame
    write_video(path, fps, frame_iter)                                    # MP4 (mp4v), streamed

What a real camera adds is drawn in on purpose: uneven lighting, sensor noise, motion blur (the
exposure's sub-frames averaged), a slight perspective tilt and barrel distortion, repeated
frames (a camera that drops one repeats the last), and a hand that covers a marker.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

# BGR of the pink dots the paper's rig carries (OpenCV hue about 163 of 180)
MARKER_BGR = (170, 60, 245)
ROD_BGR = (95, 100, 105)
HAND_BGR = (120, 160, 215)
NOISE_FIELDS = 4  # pre-drawn noise fields a frame's noise is cut from (RodScene._noise)
NOISE_MARGIN_PX = 64  # how far a frame's window may move in them [px]


@dataclass
class RodScene:
    width: int = 640
    height: int = 480
    px_per_m: float = 1000.0  # image scale at the hub [px/m]
    hub_px: tuple[float, float] | None = None  # image position of the motor axis (default: centre)
    rod_width_m: float = 0.012  # drawn width of the rod's edge-on view [m]
    marker_radius_px: float = 6.0
    noise_std: float = 4.0  # sensor noise [grey levels]
    blur_subframes: int = 3  # sub-frames averaged over the exposure (1: no motion blur)
    exposure_s: float = 0.004
    tilt: float = 0.0  # perspective: the far side of the image shrinks by this fraction
    distortion: float = 0.0  # barrel distortion k1 (normalized radius)
    seed: int = 1
    _rng: np.random.Generator = field(init=False, repr=False)
    _maps: tuple | None = field(init=False, default=None, repr=False)
    _background: np.ndarray | None = field(init=False, default=None, repr=False)
    _noise_fields: np.ndarray | None = field(init=False, default=None, repr=False)

    def __post_init__(self):
        self._rng = np.random.default_rng(self.seed)
        if self.hub_px is None:
            self.hub_px = (self.width / 2, self.height * 0.45)

    # --- the static parts -------------------------------------------------------------------
    def background(self) -> np.ndarray:
        """A light wall lit from the upper left: about 30 % darker across the frame."""
        if self._background is None:
            y, x = np.mgrid[0:self.height, 0:self.width].astype(np.float32)
            shade = 1.0 - 0.3 * (x / self.width * 0.6 + y / self.height * 0.4)
            base = np.stack([215 * shade, 222 * shade, 226 * shade], axis=-1)
            self._background = base.astype(np.float32)
        return self._background

    def _warp_maps(self):
        """cv2.remap maps of the tilt and the distortion (output pixel -> source pixel)."""
        import cv2

        if self._maps is None:
            h, w = self.height, self.width
            y, x = np.mgrid[0:h, 0:w].astype(np.float32)
            cx, cy = w / 2, h / 2
            # barrel distortion: a source point at normalized radius r appears at r (1 + k1 r^2)
            xn, yn = (x - cx) / cx, (y - cy) / cx
            r2 = xn * xn + yn * yn
            f = 1.0 / (1.0 + self.distortion * r2)
            sx, sy = cx + xn * f * cx, cy + yn * f * cx
            # tilt: rows further down are seen a little smaller (a camera pitched slightly down)
            s = 1.0 + self.tilt * (sy - cy) / h
            sx = cx + (sx - cx) * s
            self._maps = (sx.astype(np.float32), sy.astype(np.float32))
            self._cv2 = cv2
        return self._maps

    def _noise(self) -> np.ndarray:
        """One frame's sensor noise [grey levels]: a window at a random place in one of NOISE_FIELDS
        Gaussian fields drawn once. Every pixel's noise is still independent of its neighbours' and of
        its own in other frames (two frames share a window one time in 16,000); drawing a fresh field
        per frame cost most of a frame's rendering."""
        h, w = self.height, self.width
        if self._noise_fields is None:
            shape = (NOISE_FIELDS, h + NOISE_MARGIN_PX, w + NOISE_MARGIN_PX, 3)
            self._noise_fields = self._rng.standard_normal(shape, dtype=np.float32) * np.float32(self.noise_std)
        k, dy, dx = self._rng.integers((NOISE_FIELDS, NOISE_MARGIN_PX, NOISE_MARGIN_PX))
        return self._noise_fields[k, dy:dy + h, dx:dx + w]

    # --- one frame --------------------------------------------------------------------------
    def to_px(self, xy_m: np.ndarray) -> np.ndarray:
        """World [m] (x right, y up, the motor axis at 0) -> image [px] (u right, v down)."""
        hu, hv = self.hub_px
        return np.column_stack([hu + xy_m[:, 0] * self.px_per_m, hv - xy_m[:, 1] * self.px_per_m])

    def _draw(self, img: np.ndarray, nodes_m: np.ndarray, markers_m: np.ndarray, hand: np.ndarray | None) -> None:
        import cv2

        sh = 4  # fractional bits: sub-pixel drawing
        pts = np.round(self.to_px(nodes_m) * (1 << sh)).astype(np.int32)
        width = max(2, int(round(self.rod_width_m * self.px_per_m)))
        cv2.polylines(img, [pts.reshape(-1, 1, 2)], False, ROD_BGR, width, cv2.LINE_AA, sh)
        cv2.circle(img, tuple(int(v) for v in pts[0]), int(width * 1.2 * (1 << sh)), (60, 60, 60), -1, cv2.LINE_AA, sh)
        r = int(round(self.marker_radius_px * (1 << sh)))
        for p in np.round(self.to_px(markers_m) * (1 << sh)).astype(np.int32):
            cv2.circle(img, (int(p[0]), int(p[1])), r, MARKER_BGR, -1, cv2.LINE_AA, sh)
        if hand is not None:
            c = self.to_px(hand[None, :])[0]
            # a fingertip over one marker (its neighbours stay in view)
            cv2.ellipse(img, (int(c[0]), int(c[1])), (int(1.7 * self.marker_radius_px), int(1.3 * self.marker_radius_px)),
                        30, 0, 360, HAND_BGR, -1, cv2.LINE_AA)

    def render(self, shapes: list[tuple[np.ndarray, np.ndarray]], hand: np.ndarray | None = None) -> np.ndarray:
        """One frame from the rod's shapes during the exposure: [(nodes_m, markers_m), ...] (one per
        sub-frame; their mean is the motion blur). hand: a hand's centre [m] covering what is there."""
        import cv2

        acc = np.zeros((self.height, self.width, 3), np.float32)
        for nodes_m, markers_m in shapes:
            img = self.background().copy()
            self._draw(img, nodes_m, markers_m, hand)
            acc += img
        acc /= len(shapes)
        if self.tilt or self.distortion:
            mx, my = self._warp_maps()
            acc = cv2.remap(acc, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        if self.noise_std:
            acc += self._noise()
        return np.clip(acc, 0, 255).astype(np.uint8)


def checkerboard(scene: RodScene, inner: tuple[int, int] = (9, 6), square_m: float = 0.02,
                 centre_m: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """The scene's camera looking at a level checkerboard held in the rod's plane (for --calibrate)."""
    import cv2

    img = np.full((scene.height, scene.width, 3), 235, np.float32)
    cols, rows = inner[0] + 1, inner[1] + 1
    x0 = centre_m[0] - cols * square_m / 2
    y0 = centre_m[1] + rows * square_m / 2
    for i in range(cols):
        for j in range(rows):
            if (i + j) % 2:
                continue
            q = np.array([[x0 + i * square_m, y0 - j * square_m], [x0 + (i + 1) * square_m, y0 - j * square_m],
                          [x0 + (i + 1) * square_m, y0 - (j + 1) * square_m], [x0 + i * square_m, y0 - (j + 1) * square_m]])
            pts = np.round(scene.to_px(q) * 16).astype(np.int32)
            cv2.fillPoly(img, [pts.reshape(-1, 1, 2)], (25, 25, 25), cv2.LINE_AA, 4)
    if scene.tilt or scene.distortion:
        mx, my = scene._warp_maps()
        img = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return np.clip(img, 0, 255).astype(np.uint8)


def rod_nodes(theta: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Node positions [m] (x right, y up) of a chain of edges at absolute angles theta (0 hanging)."""
    d = np.column_stack([np.sin(theta) * lengths, -np.cos(theta) * lengths])
    return np.vstack([np.zeros(2), np.cumsum(d, axis=0)])


def points_at(nodes: np.ndarray, s_nodes: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Points at arc lengths s [m] along the polyline of nodes (arc length s_nodes at each node)."""
    return np.column_stack([np.interp(s, s_nodes, nodes[:, 0]), np.interp(s, s_nodes, nodes[:, 1])])


def write_video(path, fps: float, frames, size: tuple[int, int]) -> int:
    """Encode BGR frames to MP4 (the mp4v codec, OpenCV's own), streamed; returns the frame count."""
    import cv2

    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), size)
    if not w.isOpened():
        raise RuntimeError(f"OpenCV cannot write {path}")
    n = 0
    try:
        for f in frames:
            w.write(f)
            n += 1
    finally:
        w.release()
    return n


@dataclass
class Filming:
    """How the simulated run is filmed: the camera's clock against the log's, and what goes wrong."""

    fps: float = 120.0
    offset_s: float = 0.8  # the log's time of the video's first frame [s]
    drift_ppm: float = 60.0  # the camera's clock runs slow by this: log time = offset + (1 + drift) video time
    seconds: float = 5.0
    repeated_frames: tuple[int, ...] = ()  # frame k shows frame k-1 again (a dropped frame)
    hand_frames: tuple[int, int] | None = None  # frames [a, b) a hand covers a marker
    hand_marker: int = 3  # which marker (1-based from the hub)

    def log_time(self, k: np.ndarray | int) -> np.ndarray:
        return self.offset_s + (1.0 + self.drift_ppm * 1e-6) * np.asarray(k) / self.fps


def _interp_rows(t: float, tt: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """rows (one per time tt, increasing) linearly interpolated at time t, held at the ends (np.interp's
    rule for every column at once)."""
    i = int(np.clip(np.searchsorted(tt, t, side="right") - 1, 0, len(tt) - 2))
    w = min(max((t - tt[i]) / (tt[i + 1] - tt[i]), 0.0), 1.0)
    return rows[i] + w * (rows[i + 1] - rows[i])


def film(scene: RodScene, filming: Filming, t_truth: np.ndarray, theta_truth: np.ndarray, lengths: np.ndarray,
         marker_s: np.ndarray):
    """BGR frames of a simulated run (truth: time [s] and each plant edge's absolute angle, the plant's
    edge lengths [m]); markers at arc lengths marker_s [m] from the motor axis, plus one on the axis."""
    s_nodes = np.concatenate([[0.0], np.cumsum(lengths)])
    n_frames = int(round(filming.seconds * filming.fps))
    last = None
    for k in range(n_frames):
        if k in filming.repeated_frames and last is not None:
            yield last
            continue
        shapes = []
        for j in range(scene.blur_subframes):
            frac = (j + 0.5) / scene.blur_subframes - 0.5
            t = float(filming.log_time(k)) + frac * scene.exposure_s
            th = _interp_rows(t, t_truth, theta_truth)
            nodes = rod_nodes(th, lengths)
            markers = np.vstack([np.zeros((1, 2)), points_at(nodes, s_nodes, marker_s)])
            shapes.append((nodes, markers))
        hand = None
        if filming.hand_frames and filming.hand_frames[0] <= k < filming.hand_frames[1]:
            hand = shapes[len(shapes) // 2][1][filming.hand_marker]
        last = scene.render(shapes, hand)
        yield last


def simulate_filmed_run(params, path, *, swing_deg: float = 50.0, free_s: float = 3.0, armed_s: float = 5.0,
                        after_s: float = 3.0, still_s: float = 0.0):
    """A run filmed as docs/howto/film-a-run.md says: the rod hangs still at rest for `still_s` [s] (default
    none; its static shape, the hub vertical, the log DISARMED and the encoder still: what
    rodctl.track.rest_shape measures the rest curvature from), then is let go from `swing_deg` [deg] and swings
    freely with the driver off for `free_s` [s] (the hand's swing that times the video), the board swings it up
    and balances it for `armed_s` [s], then is disarmed and the rod falls and swings for `after_s` [s]. Writes
    the telemetry log `path` (and its .truth.csv, as `rodctl sim --log` does);
    returns (truth time [s], truth edge angles [rad] (T, plant edges), plant edge lengths [m])."""
    import math
    from types import SimpleNamespace

    from rodctl.build.sil_build import build_sil
    from rodctl.sim.scenario_run import write_log
    from rodctl.sim.plant import SilController, faithful_plant, run_closed_loop
    from rodctl.sim.scenarios import Trace

    pl = faithful_plant(params, input_mode="duty")
    ctl = SilController(build_sil(params))
    dt = params.dt
    parts = []
    if still_s > 0:
        parts.append(_hang_still(pl, ctl, params, int(round(still_s / dt))))
    pl.set_state(math.radians(swing_deg))  # a hand lifts the rod between two control periods and lets go
    parts.append(run_closed_loop(pl, ctl, int(round(free_s / dt)), arm_mode=0, reset=not parts))
    ctl.lib.rod_sil_arm(2)  # swing-up
    parts.append(run_closed_loop(pl, ctl, int(round(armed_s / dt)), reset=False))
    if after_s > 0:
        ctl.lib.rod_sil_arm(0)  # disarm: the rod falls from upright and swings
        parts.append(run_closed_loop(pl, ctl, int(round(after_s / dt)), reset=False))
    log = {k: np.concatenate([p[k] for p in parts]) for k in parts[0] if isinstance(parts[0][k], np.ndarray)}
    arc = pl.node_arc()
    trace = Trace("filmed", log["time"], log["theta"], log["torque"], float(arc[-1] - arc[-2]),
                  est=log["est"].astype(float), mode=log["mode"], duty=log["duty"], count=log["count"],
                  torque_cmd=log["torque_cmd"], node_arc=arc)
    write_log(SimpleNamespace(params=params, name="filmed"), trace, Path(path))
    return log["time"], log["theta"], np.diff(arc)


def _hang_still(pl, ctl, params, periods: int) -> dict:
    """The closed loop's log of `periods` control periods, disarmed from boot, with the rod `pl` hanging at rest in
    its static shape (rodctl.sim.statics.hanging_nodes), the hub vertical and still.

    The plant's Coulomb friction is smoothed (a slope through zero speed), so a curved rod's moment would make the
    motor creep (0.13 deg/s for the matrix's 0.82 1/m: the encoder's count changed within the first second) and,
    from the middle of the gearbox's play, first swing the rod across it (1.1 deg at the tip). A real
    gearmotor's static friction holds the hub: here an external torque on the shaft, the static shape's own,
    does (the hub then moved 0.013 deg in 2 s)."""
    from rodctl.sim.plant import run_closed_loop
    from rodctl.sim.statics import hanging_nodes

    nodes = hanging_nodes(params)
    pl.set_state(np.arctan2(np.diff(nodes[:, 0]), -np.diff(nodes[:, 1])))
    q, _ = pl.raw_state()
    # the generalized force on the hub's coordinate (the first) at rest: what holds it still, negated
    pl.external_torque = -float(pl.force(np.concatenate([q, np.zeros(pl.n)]))[0])
    try:
        return run_closed_loop(pl, ctl, periods, arm_mode=0, reset=True)
    finally:
        pl.external_torque = 0.0


TEST_SWING_AMPLITUDE = 0.012  # [N m]: a slow swing-up, so the base swings through the whole clip
DEMO_SWING = (f"swing_up.amplitude={TEST_SWING_AMPLITUDE}", "swing_up.stall_steps=0")  # its plateau kept


def demo(folder, fps: float = 120.0, seconds: float = 8.0, *, scene: RodScene | None = None,
         filming: Filming | None = None, params=None) -> dict:
    """A filmed simulated run in `folder`: run.csv (+ .truth.csv), run.mp4 and board.png (a checkerboard
    9x6, 20 mm, in the rod's plane). The swing-up is slowed (swing_up.amplitude TEST_SWING_AMPLITUDE) and
    its stall watch is off (it would raise the pump at the plateau) so the rod swings through the whole
    clip; the camera adds tilt, distortion, noise, blur, two repeated frames and a hand over marker 3.
    Returns the paths and the filming."""
    import cv2
    from rodgains.params import load_params

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    p = (params or load_params()).with_overrides(*DEMO_SWING)
    log = folder / "run.csv"
    t, th, lengths = simulate_filmed_run(p, log, swing_deg=0.0, free_s=0.2, armed_s=seconds + 1.0, after_s=0.0)
    scene = scene or RodScene(width=480, height=360, px_per_m=900.0, tilt=0.03, distortion=0.03)
    n = int(round(seconds * fps))
    filming = filming or Filming(fps=fps, offset_s=0.6, drift_ppm=60.0, seconds=seconds,
                                 repeated_frames=(n // 8, n // 3), hand_frames=(n // 2, n // 2 + int(fps / 4)))
    marker_s = np.linspace(0.0, float(p["rod"]["length"]), int(p["rod"]["edges"]) + 1)[1:]
    video = folder / "run.mp4"
    write_video(video, fps, film(scene, filming, t, th, lengths, marker_s), (scene.width, scene.height))
    board = folder / "board.png"
    cv2.imwrite(str(board), checkerboard(scene, (9, 6), 0.02, (0.0, -0.03)))
    return {"log": log, "truth": folder / "run.truth.csv", "video": video, "board": board, "filming": filming,
            "params": p, "lengths": lengths}


def main(argv: list[str] | None = None) -> int:
    """python -m rodctl.track.render [DIR] [--fps F] [--seconds S]: the docs' example video."""
    import argparse

    ap = argparse.ArgumentParser(prog="python -m rodctl.track.render",
                                 description="Render a simulated filmed run for `rodctl track`: DIR/run.csv (the "
                                             "telemetry log, and its .truth.csv), DIR/run.mp4 and DIR/board.png (a "
                                             "9x6 checkerboard, 20 mm squares, in the rod's plane).")
    ap.add_argument("folder", nargs="?", default="build/track-demo", metavar="DIR",
                    help="where to write (default build/track-demo)")
    ap.add_argument("--fps", type=float, default=120.0, help="the camera's frame rate [1/s] (default 120)")
    ap.add_argument("--seconds", type=float, default=8.0, help="the clip's length [s] (default 8)")
    args = ap.parse_args(argv)
    if not 1 <= args.fps <= 1000 or not 1 <= args.seconds <= 600:
        ap.error("--fps from 1 to 1000, --seconds from 1 to 600")
    out = demo(args.folder, fps=args.fps, seconds=args.seconds)
    print(f"wrote {out['video']}, {out['log']}, {out['board']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
