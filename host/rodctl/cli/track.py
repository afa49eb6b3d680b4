"""rodctl track: the rod a camera saw against the board's estimate (rodctl.track)."""

from __future__ import annotations

import math
from pathlib import Path

from rodgains.atomic_file import replacing
from rodgains.errors import InputError

from rodctl.cli.outputs import check_output

BOARD_DEFAULT = "9x6"  # the checkerboard's inner corners, COLSxROWS
SQUARE_DEFAULT_M = 0.02  # its square side [m]


def _pair(text: str | None, what: str) -> tuple[float, float] | None:
    if text is None:
        return None
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"{what} {text!r}: expected X,Y") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise InputError(f"{what} {text!r}: expected X,Y in pixels, finite numbers")
    return x, y


def _times(text: str | None) -> list[float] | None:
    if not text:
        return None
    try:
        times = [float(v) for v in text.split(",")]
    except ValueError:
        times = []
    if not times or not all(math.isfinite(v) for v in times):
        raise InputError(f"--at {text!r}: times [s] on the log's clock, comma-separated")
    return times


def _panel_times(at: list[float] | None, t, ok) -> list[float]:
    """The shape panels' times [s]: --at's, each inside the span the video tracked, else four across it."""
    import numpy as np

    if not ok.any():
        raise InputError("--plot: no frame of the video was tracked, so there is no shape to draw")
    first, last = float(t[ok][0]), float(t[ok][-1])
    if at is None:
        return list(np.linspace(first, last, 6)[1:-1])
    outside = [v for v in at if not first <= v <= last]
    if outside:
        raise InputError(f"--at {','.join(f'{v:g}' for v in outside)}: outside the tracked span, "
                         f"{first:.2f} to {last:.2f} s on the log's clock")
    return at


def run_track_command(args) -> int:
    import numpy as np
    from rodgains.params import load_params

    from rodctl.track import track
    from rodctl.track.compare import table_lines
    from rodctl.track.markers import ColorRange
    from rodctl.track.output import columns, rest_shape_meta, write_mcap, write_parquet
    from rodctl.track.shape import QUALITY_TEXT

    # every input and output checked before the video is read
    color = ColorRange.parse(args.color)
    hub = _pair(args.hub, "--hub")
    if args.scale is not None and not 0 < args.scale < 1:
        raise InputError(f"--scale {args.scale:g}: metres per pixel, e.g. 0.0005 (a 155 mm rod across 310 px)")
    if args.markers is not None and not 2 <= args.markers <= 64:
        raise InputError(f"--markers {args.markers}: between 2 and 64 markers on the rod")
    at = _times(args.at)
    if at is not None and not args.plot:
        raise InputError(f"--at {args.at}: times of the figure's shape panels; add --plot PNG")
    out = Path(args.out)
    if out.suffix.lower() != ".parquet":
        raise InputError(f"--out {out}: the tracked log is Parquet (.parquet); its MCAP goes beside it")
    check_output(out, "--out", force=args.force)
    check_output(out.with_suffix(".mcap"), "--out's MCAP", force=args.force)
    if args.plot is not None:  # an empty name is refused, not taken for no figure
        check_output(args.plot, "--plot", figure=True, force=args.force)
    for path, what in ((args.video, "video"), (args.log, "--log")):
        if Path(path).is_dir():
            raise InputError(f"{what} {path}: is a folder, not a file")
        if not Path(path).is_file():
            raise InputError(f"{what} {path}: no such file")
    params = load_params(args.params, args.overrides) if (args.params or args.overrides) else None
    view = None
    if not args.calibrate and (args.board is not None or args.square is not None):
        raise InputError(f"{'--board' if args.board is not None else '--square'}: describes the checkerboard of "
                         "--calibrate IMAGE, which is not given")
    if args.calibrate:
        from rodctl.track.calibrate import View

        board = args.board if args.board is not None else BOARD_DEFAULT
        square = args.square if args.square is not None else SQUARE_DEFAULT_M
        try:
            cols, rows = (int(v) for v in board.lower().split("x"))
        except ValueError:
            raise InputError(f"--board {board!r}: inner corners as COLSxROWS, e.g. 9x6") from None
        if cols < 3 or rows < 3:
            raise InputError(f"--board {board!r}: at least 3x3 inner corners, e.g. 9x6")
        view = View.from_checkerboard(args.calibrate, (cols, rows), square)
        print(f"calibration: {args.calibrate}, reprojection {view.rms_px:.2f} px, k1 {view.dist.ravel()[0]:+.3f}")

    bar = None

    def progress(k, total):
        # the bar starts with the first frame read: a refused log or video is its one line of error, nothing else
        nonlocal bar
        if args.quiet:
            return
        if bar is None:
            from rodctl.progress import bar as progress_bar

            bar = progress_bar(total=total or None, desc="track", unit="frame", leave=False)
        if bar.total is None and total:
            bar.total = total
        bar.update(k - bar.n)

    try:
        r = track(args.video, args.log, params, markers=args.markers, color=color, hub=hub, scale=args.scale,
                  view=view, filmed_fps=args.fps, progress=progress)
    finally:
        if bar is not None:
            bar.close()
    if r.rest_shape is None:  # track() says a measured one itself
        print(r.rest_note)
    a = r.alignment
    q = r.counts()
    print(f"video: {r.frames} frames at {r.fps:g} fps; hub at ({r.hub_px[0]:.1f}, {r.hub_px[1]:.1f}) px, "
          f"{r.m_per_px * 1e3:.4f} mm/px")
    # a repeat is a camera's dropped frame, or a frame its encoder skipped (a low bit rate): either shows the frame
    # before at the wrong time, so it is not compared
    print(f"frames: {q['good']} {QUALITY_TEXT[0]}, {q['filled']} with {QUALITY_TEXT[1]}, {q['repeated']} "
          f"{QUALITY_TEXT[3].replace('a ', '')}s (dropped by the camera or skipped by its encoder), {q['unusable']} "
          f"with {QUALITY_TEXT[2]}")
    print(f"alignment: the video's first frame at {a.offset_s:.4f} s of the log, {a.drift_text()}, "
          f"base angle correlation {a.correlation:.4f}, residual {np.degrees(a.residual_rad):.2f} deg, "
          f"camera minus encoder {np.degrees(a.angle_offset_rad):+.2f} deg")
    print("estimate minus video, per edge:")
    for line in table_lines(r.errors):
        print("  " + line)

    if args.plot:  # the panels' times checked before anything is written
        times = _panel_times(at, r.time_s, np.isfinite(r.theta).all(axis=1))
    meta = {"video": args.video, "log": args.log, "fps": r.fps, "slowdown": a.slowdown,
            "fps_note": "the rate filmed; video_time_s is the file's clock (slowdown x)",
            "offset_s": a.offset_s, "drift_ppm": a.drift_ppm, "drift_measured": a.drift_measured,
            "drift_sd_ppm": a.drift_sd_ppm, "correlation": a.correlation, "mirrored": a.mirrored,
            "m_per_px": r.m_per_px, "hub_px": f"{r.hub_px[0]:.2f},{r.hub_px[1]:.2f}",
            "quality": "0 every marker seen, 1 a marker filled in, 2 too few markers, 3 a repeated frame"}
    meta.update(rest_shape_meta(r.rest_shape, r.rest_note))
    cols = columns(r.time_s, r.video_time_s, r.theta, r.markers_m, r.quality)
    write_parquet(out, cols, meta)
    mcap = out.with_suffix(".mcap")
    write_mcap(mcap, cols, meta)
    written = [str(out), str(mcap)]
    if args.plot:
        from rodctl.track.figures import tracking_figure

        length = float((params or load_params())["rod"]["length"])
        fig = tracking_figure(r.time_s, r.theta, r.estimate, length, times,
                              f"{Path(args.video).name} against {Path(args.log).name}")
        with replacing(args.plot) as tmp:  # whole or not at all, as the tracked logs
            fig.savefig(tmp, dpi=110, format=Path(args.plot).suffix.lstrip(".").lower())
        written.append(args.plot)
    print(f"wrote {', '.join(written)}")
    return 0


def register(sub) -> None:
    p = sub.add_parser(
        "track", help="ground truth from video: the rod's markers against the board's estimate",
        description="Find the rod's colored markers in every frame of VIDEO (OpenCV, streamed), take the hub from "
                    "the marker that holds still on the motor axis, the scale from the rod's length (or --scale, "
                    "or a checkerboard with --calibrate), align the video's clock with the telemetry LOG by the "
                    "base angle both saw (offset and drift), and compare every edge's angle with the board's "
                    "estimate. Writes a tracked log (Parquet, and MCAP beside it for Foxglove) on the log's clock, "
                    "and a figure with --plot. How to film a run: docs/howto/film-a-run.md. Exit 2: bad input, "
                    "a video without the markers, or a log of another run.")
    p.add_argument("video", metavar="VIDEO", help="the video (any format OpenCV reads, e.g. MP4)")
    p.add_argument("--log", required=True, metavar="LOG", help="the run's telemetry log (CSV, Parquet or MCAP)")
    p.add_argument("--out", default="tracked.parquet", metavar="PATH",
                   help="tracked log (default tracked.parquet; the MCAP goes beside it)")
    p.add_argument("--plot", metavar="PNG", help="figure: shapes at --at times, and every edge's angle over time")
    p.add_argument("--at", metavar="T1,T2,...", help="times [s, the log's clock] of the shape panels (default: 4 "
                                                     "spread over the video)")
    p.add_argument("--markers", type=int, metavar="N", help="markers on the rod besides the axis's, equally spaced, "
                                                            "the last at the tip (default: the design's N)")
    p.add_argument("--color", metavar="H1,S1,V1-H2,S2,V2",
                   help="the markers' HSV range in OpenCV units (H 0..179, H1 > H2 wraps through red; default pink "
                        "145,90,90-179,255,255)")
    p.add_argument("--hub", metavar="X,Y", help="the motor axis in the image [px] (default: the marker that holds "
                                                 "still)")
    p.add_argument("--scale", type=float, metavar="M_PER_PX", help="metres per pixel (default: from the rod's "
                                                                    "length)")
    p.add_argument("--fps", type=float, metavar="F", help="the rate the video was filmed at [frames/s] (default: "
                                                          "the file's, or a slow-motion file's factor of it, found "
                                                          "from the swing; say it for a factor the search misses)")
    p.add_argument("--calibrate", metavar="IMAGE", help="a checkerboard held level in the rod's plane: removes the "
                                                        "lens distortion and the tilt, and gives the scale")
    p.add_argument("--board", metavar="COLSxROWS", help="the checkerboard's inner corners (default 9x6)")
    p.add_argument("--square", type=float, metavar="M", help="its square side [m] (default 0.02)")
    p.add_argument("--params", metavar="FILE", help="the rod's parameter file (default: the log's parameters)")
    p.add_argument("--set", metavar="SECTION.KEY=VALUE", action="append", default=[], dest="overrides",
                   help="override one parameter (repeatable)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--force", action="store_true", help="overwrite an existing --out (and the MCAP beside it) or --plot")
    p.set_defaults(func=run_track_command)
