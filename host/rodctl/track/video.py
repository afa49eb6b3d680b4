"""Frames of a video, streamed (never the whole video in memory), with their index."""

from __future__ import annotations

from pathlib import Path

from rodgains.errors import InputError


class Video:
    def __init__(self, path: str | Path):
        import cv2

        self.path = Path(path)
        if not self.path.is_file():
            raise InputError(f"video {path}: no such file")
        self.cap = cv2.VideoCapture(str(self.path))
        ok = self.cap.isOpened()
        self.fps = float(self.cap.get(cv2.CAP_PROP_FPS)) if ok else 0.0
        self.frames = int(self.cap.get(cv2.CAP_PROP_FRAME_COUNT)) if ok else 0
        self.width = int(self.cap.get(cv2.CAP_PROP_FRAME_WIDTH)) if ok else 0
        self.height = int(self.cap.get(cv2.CAP_PROP_FRAME_HEIGHT)) if ok else 0
        if not ok or not self.fps > 0 or self.width <= 0:
            self.cap.release()
            raise InputError(f"video {path}: OpenCV cannot read it as a video")

    def __iter__(self):
        try:
            while True:
                ok, frame = self.cap.read()
                if not ok:
                    return
                yield frame
        finally:
            self.cap.release()
