"""Frames of a video, streamed (never the whole video in memory), with their index and time.

OpenCV's FFmpeg backend prints FFmpeg's own complaints ("moov atom not found", "ac-tex damaged")
straight to stderr; a bad video is reported in one line of ours, so they are silenced (FFmpeg
reads OPENCV_FFMPEG_LOGLEVEL when the first video is opened; a level the user set is kept).
"""

from __future__ import annotations

import os
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from rodgains.errors import InputError

os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # AV_LOG_QUIET
UNEVEN_SHARE = 0.25  # a frame interval this far from the median interval makes the timing uneven [-]


@contextmanager
def quiet_opencv():
    """OpenCV's own log (its warnings about the backends it tried) off while opening and reading."""
    import cv2

    try:
        level = cv2.utils.logging.getLogLevel()
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    except AttributeError:  # an OpenCV without the logging module: nothing to silence
        level = None
    try:
        yield
    finally:
        if level is not None:
            cv2.utils.logging.setLogLevel(level)


class Video:
    def __init__(self, path: str | Path):
        import cv2

        self.path = Path(path)
        if not self.path.is_file():
            raise InputError(f"video {path}: no such file")
        with quiet_opencv():
            self.cap = cv2.VideoCapture(str(self.path))
        ok = self.cap.isOpened()
        self.fps = float(self.cap.get(cv2.CAP_PROP_FPS)) if ok else 0.0
        self.frames = int(self.cap.get(cv2.CAP_PROP_FRAME_COUNT)) if ok else 0
        self.width = int(self.cap.get(cv2.CAP_PROP_FRAME_WIDTH)) if ok else 0
        self.height = int(self.cap.get(cv2.CAP_PROP_FRAME_HEIGHT)) if ok else 0
        self.stamps_ms: list[float] = []  # the container's time of each frame read [ms]
        if not ok or not self.fps > 0 or self.width <= 0:
            self.cap.release()
            raise InputError(f"video {path}: OpenCV cannot read it as a video")

    def __iter__(self):
        import cv2

        try:
            with quiet_opencv():
                while True:
                    ok, frame = self.cap.read()
                    if not ok:
                        return
                    self.stamps_ms.append(float(self.cap.get(cv2.CAP_PROP_POS_MSEC)))
                    yield frame
        finally:
            self.cap.release()

    def frame_times(self, count: int) -> tuple[np.ndarray, str | None]:
        """(time of each of the first `count` frames read [s] from the first, a one-line warning or None).

        index / fps when the container's timestamps are even (so a constant-rate file is timed
        exactly, not to the container's rounding: MKV keeps milliseconds) or unusable (missing, not
        increasing); the timestamps themselves when they are uneven: a phone's variable frame rate,
        or a camera that left out frames and said so."""
        uniform = np.arange(count) / self.fps
        ts = np.asarray(self.stamps_ms[:count], float) / 1e3
        if len(ts) != count or count < 3 or not np.all(np.isfinite(ts)) or np.any(np.diff(ts) <= 0):
            return uniform, None
        dt = np.diff(ts)
        med = float(np.median(dt))
        uneven = np.abs(dt - med) > UNEVEN_SHARE * med
        if not uneven.any():
            return uniform, None
        warning = (f"{self.path}: uneven frame timing ({int(uneven.sum())} of {len(dt)} intervals differ from "
                   f"{med * 1e3:.2f} ms by over {UNEVEN_SHARE:.0%}, {dt.min() * 1e3:.2f} to {dt.max() * 1e3:.2f} ms): "
                   "the frames are timed by the container's timestamps")
        return ts - ts[0], warning
