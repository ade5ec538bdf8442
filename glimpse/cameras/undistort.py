"""Removing lens distortion once, in stage 01 (later stages see pinhole frames only).

The output keeps the input K: undistorted pixel (u, v) looks along K^-1 [u, v, 1].
"""

from __future__ import annotations

import cv2
import numpy as np


class Undistorter:
    """Undistorts images, masks and pixel coordinates of one camera.

    K: (3, 3) intrinsics (OpenCV pixel convention); dist: (4,) or (5,) OpenCV
    coefficients [k1, k2, p1, p2(, k3)], or None for a pinhole input (identity).
    """

    def __init__(self, K: np.ndarray, dist: np.ndarray | None, width: int, height: int):
        self.K = np.asarray(K, dtype=np.float64)
        self.dist = None if dist is None or not np.any(dist) else np.asarray(dist, dtype=np.float64)
        self.maps = None
        if self.dist is not None:
            self.maps = cv2.initUndistortRectifyMap(self.K, self.dist, None, self.K, (width, height), cv2.CV_32FC1)

    @property
    def active(self) -> bool:
        return self.dist is not None

    def image(self, image: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 -> undistorted (H, W, 3) uint8 (bilinear)."""
        if self.maps is None:
            return image
        return cv2.remap(image, *self.maps, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)

    def mask(self, mask: np.ndarray) -> np.ndarray:
        """(H, W) bool -> undistorted (H, W) bool (nearest neighbour)."""
        if self.maps is None:
            return mask
        warped = cv2.remap(mask.astype(np.uint8), *self.maps, interpolation=cv2.INTER_NEAREST)
        return warped.astype(bool)

    def points(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2) distorted pixel coordinates -> (N, 2) undistorted pixel coordinates."""
        if self.dist is None or len(xy) == 0:
            return xy
        out = cv2.undistortPoints(np.asarray(xy, np.float64).reshape(-1, 1, 2), self.K, self.dist, P=self.K)
        return out.reshape(-1, 2)


def scene_undistorter(scene) -> Undistorter:
    """The undistorter of a scene's input camera (the identity for a pinhole or camera-less scene).
    scene: glimpse.scene.Scene."""
    cameras = scene.cameras
    return Undistorter(cameras.K if cameras is not None and cameras.K is not None else np.eye(3),
                       cameras.dist if cameras is not None else None, scene.width, scene.height)
