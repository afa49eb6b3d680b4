"""The rod's colored markers in one frame: an HSV range, OpenCV's thresholding and its connected
components (no home-made blob detector)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rodgains.errors import InputError

# The paper's rig carries pink dots: OpenCV hue (0..179) about 150 to 178, well saturated, not dark.
DEFAULT_HSV = ((145, 90, 90), (179, 255, 255))


@dataclass(frozen=True)
class ColorRange:
    lo: tuple[int, int, int]
    hi: tuple[int, int, int]

    @classmethod
    def parse(cls, text: str | None) -> "ColorRange":
        """'H1,S1,V1-H2,S2,V2' (OpenCV units: H 0..179, S and V 0..255); H1 > H2 wraps through red (170 to 10:
        '170,90,90-10,255,255'), as a red or pink marker under warm light straddles hue 0. None: the default pink."""
        if text is None:
            return cls(*DEFAULT_HSV)
        try:
            lo_t, hi_t = text.split("-")
            lo = tuple(int(v) for v in lo_t.split(","))
            hi = tuple(int(v) for v in hi_t.split(","))
        except ValueError:
            raise InputError(f"--color {text!r}: expected H1,S1,V1-H2,S2,V2, e.g. 145,90,90-179,255,255") from None
        if len(lo) != 3 or len(hi) != 3:
            raise InputError(f"--color {text!r}: three numbers on each side (H,S,V)")
        if not (0 <= lo[0] <= 179 and 0 <= hi[0] <= 179):
            raise InputError(f"--color {text!r}: H must be within 0..179 (low > high wraps through red)")
        for name, v, top in zip("SV", zip(lo[1:], hi[1:]), (255, 255)):
            if not (0 <= v[0] <= v[1] <= top):
                raise InputError(f"--color {text!r}: {name} must be 0 <= low <= high <= {top}")
        return cls(lo, hi)

    def mask(self, hsv: np.ndarray) -> np.ndarray:
        """255 where an HSV image's pixel is in the range, 0 elsewhere (OpenCV's inRange, twice when it wraps)."""
        import cv2

        lo, hi = np.array(self.lo, np.uint8), np.array(self.hi, np.uint8)
        if lo[0] <= hi[0]:
            return cv2.inRange(hsv, lo, hi)
        top = np.array([179, hi[1], hi[2]], np.uint8)
        bottom = np.array([0, lo[1], lo[2]], np.uint8)
        return cv2.inRange(hsv, lo, top) | cv2.inRange(hsv, bottom, hi)


class Detector:
    """Marker centroids [px] in BGR frames, sub-pixel (the mean of the blob's pixels)."""

    MIN_AREA_PX = 6  # smaller blobs are noise

    def __init__(self, color: ColorRange, max_area_px: float = 5000.0):
        import cv2

        self.cv2 = cv2
        self.color = color
        self.max_area = max_area_px
        self.kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))

    def __call__(self, frame: np.ndarray) -> np.ndarray:
        """(n, 3): centroid x, y [px] and area [px] of each blob. A blob touching the image's border
        is left out: the part outside the image is missing, so its centroid is shifted inwards (a
        marker half out of view moved an edge's angle by 4 to 6 deg); out of view, it is not seen."""
        cv2 = self.cv2
        hsv = cv2.cvtColor(frame, cv2.COLOR_BGR2HSV)
        mask = self.color.mask(hsv)
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, self.kernel)
        # labelled within the box round the marked pixels only: over a whole 720p frame OpenCV 5's labelling
        # takes 6 ms, three times the decode; within the rod's few hundred pixels, 0.4 ms
        x0, y0, w, h = cv2.boundingRect(mask)
        if w == 0 or h == 0:
            return np.zeros((0, 3))
        n, _, stats, centroids = cv2.connectedComponentsWithStats(mask[y0:y0 + h, x0:x0 + w], connectivity=8)
        if n <= 1:
            return np.zeros((0, 3))
        stats = stats[1:].copy()
        stats[:, cv2.CC_STAT_LEFT] += x0
        stats[:, cv2.CC_STAT_TOP] += y0
        centroids = centroids + (x0, y0)
        area = stats[:, cv2.CC_STAT_AREA]
        keep = (area >= self.MIN_AREA_PX) & (area <= self.max_area) & ~self._on_border(stats, mask.shape)
        return np.column_stack([centroids[1:][keep], area[keep]]).astype(float)

    def _on_border(self, stats: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """Per blob: its bounding box touches the image's edge."""
        cv2 = self.cv2
        x, y = stats[:, cv2.CC_STAT_LEFT], stats[:, cv2.CC_STAT_TOP]
        w, h = stats[:, cv2.CC_STAT_WIDTH], stats[:, cv2.CC_STAT_HEIGHT]
        return (x <= 0) | (y <= 0) | (x + w >= shape[1]) | (y + h >= shape[0])
