"""How fast `rodctl track` reads a 720p video: the streamed pass (decode, marker detection, repeat
check), frames per wall second, on a rendered clip of the simulated rod (bench-track-720p.mp4 in the build folder)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from rodctl import paths

CLIP = paths.BUILD / "bench-track-720p.mp4"


def make_clip(path: Path = CLIP, fps: float = 60.0, seconds: float = 3.0) -> Path:
    from rodgains.params import load_params

    from rodctl.track.render import RodScene, film, Filming, simulate_filmed_run, write_video

    if path.exists():
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    p = load_params()
    log = path.with_suffix(".csv")
    t, th, lengths = simulate_filmed_run(p, log, swing_deg=40.0, free_s=0.5, armed_s=seconds, after_s=0.0)
    scene = RodScene(width=1280, height=720, px_per_m=1900.0, blur_subframes=1, seed=2)
    marker_s = np.linspace(0.0, float(p["rod"]["length"]), int(p["rod"]["edges"]) + 1)[1:]
    tmp = path.with_name(path.stem + ".partial.mp4")
    write_video(tmp, fps, film(scene, Filming(fps=fps, offset_s=0.2, seconds=seconds), t, th, lengths, marker_s),
                (1280, 720))
    tmp.replace(path)
    return path


def measure(quick: bool = False) -> dict:
    from rodctl.track import detect_all
    from rodctl.track.markers import ColorRange, Detector
    from rodctl.track.video import Video

    clip = make_clip()
    best = 0.0
    for _ in range(1 if quick else 3):
        video = Video(clip)
        t0 = time.perf_counter()
        dets, _ = detect_all(video, Detector(ColorRange.parse(None)))
        best = max(best, len(dets) / (time.perf_counter() - t0))
    return {"track_720p_frames_per_s": round(best, 1)}
