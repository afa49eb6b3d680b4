"""The camera's view of the rod's plane from one checkerboard image held in that plane, level.

    view = View.from_checkerboard("board.png", inner=(9, 6), square_m=0.02)
    xy_m = view.to_plane(centroids_px)        # metric coordinates in the rod's plane, y up

OpenCV finds the corners (sub-pixel), fits the lens (focal length and the first radial distortion
term, the principal point held at the centre: one view cannot tell more), removes the distortion
from the corners and maps them onto the board: a homography from the undistorted image to the
plane. Tilt, distortion and scale all go at once; the board's rows give the horizontal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rodgains.errors import InputError


@dataclass
class View:
    K: np.ndarray  # camera matrix [px]
    dist: np.ndarray  # OpenCV distortion coefficients (k1, k2, p1, p2, k3)
    H: np.ndarray  # undistorted image [px] -> plane [m], y down along the board's columns
    rms_px: float  # reprojection error of the fit [px]

    @classmethod
    def from_checkerboard(cls, path, inner: tuple[int, int], square_m: float) -> "View":
        import cv2

        if not square_m > 0 or not square_m < 1:
            raise InputError(f"--square {square_m!r}: the checkerboard's square side in metres, e.g. 0.02")
        from rodctl.track.video import quiet_opencv

        with quiet_opencv():  # OpenCV's own "can't open/read file" warning: the line below says it
            img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise InputError(f"--calibrate {path}: not an image OpenCV can read")
        try:
            found, corners = cv2.findChessboardCorners(img, inner,
                                                       cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
        except cv2.error:  # an image too small for its adaptive threshold: no board in it either
            found = False
        if not found:
            raise InputError(f"--calibrate {path}: no {inner[0]}x{inner[1]} checkerboard (inner corners) found")
        corners = cv2.cornerSubPix(img, corners, (5, 5), (-1, -1),
                                   (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4))
        obj = np.zeros((inner[0] * inner[1], 3), np.float32)
        obj[:, :2] = np.mgrid[0:inner[0], 0:inner[1]].T.reshape(-1, 2) * square_m
        h, w = img.shape
        K0 = np.array([[w, 0, w / 2], [0, w, h / 2], [0, 0, 1]], float)
        flags = (cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_PRINCIPAL_POINT | cv2.CALIB_FIX_ASPECT_RATIO
                 | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3)
        rms, K, dist, _, _ = cv2.calibrateCamera([obj], [corners], (w, h), K0, np.zeros(5), flags=flags)
        und = cv2.undistortPoints(corners, K, dist, P=K).reshape(-1, 2)
        H, _ = cv2.findHomography(und, obj[:, :2])
        # the corner order may start at any corner: make the plane's x grow to the image's right and
        # its y (down the board) to the image's bottom
        c = np.array([[[w / 2, h / 2]], [[w / 2 + 10, h / 2]], [[w / 2, h / 2 + 10]]], np.float64)
        p = cv2.perspectiveTransform(c, H).reshape(-1, 2)
        fx = 1.0 if p[1, 0] > p[0, 0] else -1.0
        fy = 1.0 if p[2, 1] > p[0, 1] else -1.0
        H = np.diag([fx, fy, 1.0]) @ H
        return cls(K, dist, H, float(rms))

    def to_plane(self, pts_px: np.ndarray) -> np.ndarray:
        """Image points [px] (n, 2) -> the rod's plane [m], x along the board's rows, y up."""
        import cv2

        if len(pts_px) == 0:
            return np.zeros((0, 2))
        und = cv2.undistortPoints(np.asarray(pts_px, np.float64).reshape(-1, 1, 2), self.K, self.dist, P=self.K)
        plane = cv2.perspectiveTransform(und, self.H).reshape(-1, 2)
        return np.column_stack([plane[:, 0], -plane[:, 1]])
