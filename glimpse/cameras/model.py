"""The camera type every stage shares, :class:`PinholeCamera` (OpenCV pinhole, world-to-camera, with its image
size), and its conversions: to the rasterizer's camera (:func:`render_camera`), to another image size
(:meth:`PinholeCamera.resized`), from a scene's per-frame pose (:func:`camera_from_pose`). File formats that hold
cameras (cameras.json, COLMAP text models) read into and write from this type in glimpse.io."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # torch is imported where it is used: reading a scene (make's every step) does not need it
    import torch

    from glimpse.render import Camera


@dataclass(frozen=True)
class PinholeCamera:
    """One camera at one instant.

    K: (3, 3) intrinsics; the centre of the top-left pixel is at (0, 0) (OpenCV).
    R: (3, 3) world-to-camera rotation; t: (3,) translation: x_cam = R @ x_world + t (world units).
    width, height: the image size in pixels.
    """

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int
    height: int

    @property
    def centre(self) -> np.ndarray:
        """(3,) camera centre in the world frame: -R^T t."""
        return -self.R.T @ self.t

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) world points -> ((N, 2) pixels, (N,) depth along the optical axis).
        Points at or behind the camera get non-finite or meaningless pixels: check depth > 0."""
        cam = points @ self.R.T + self.t
        with np.errstate(divide="ignore", invalid="ignore"):
            pixels = cam[:, :2] / cam[:, 2:3] * [self.K[0, 0], self.K[1, 1]] + self.K[:2, 2]
        return pixels, cam[:, 2]

    def resized(self, width: int, height: int) -> PinholeCamera:
        """The same view in an image of ``width`` x ``height`` pixels (pixel centres stay pixel centres)."""
        scale = np.array([width / self.width, height / self.height])
        K = self.K.copy()
        K[:2] *= scale[:, None]
        K[:2, 2] = (self.K[:2, 2] + 0.5) * scale - 0.5
        return replace(self, K=K, width=width, height=height)


def camera_from_pose(K: np.ndarray, R: np.ndarray, t: np.ndarray, width: int, height: int,
                     pose_K: np.ndarray | None = None) -> PinholeCamera:
    """A camera of shared intrinsics ``K`` at a pose ``R, t``, with that instant's own ``pose_K`` (a zoom) where
    given (the scene format's cameras.json and eval/cameras.json)."""
    return PinholeCamera(pose_K if pose_K is not None else K, R, t, width, height)


def default_intrinsics(width: int, height: int, fov_deg: float) -> np.ndarray:
    """(3, 3) K with the given field of view across the larger image side, centred.

    The principal point is the image centre in OpenCV's convention: ((W-1)/2, (H-1)/2).
    """
    if not 0.0 < fov_deg < 180.0:
        raise ValueError(f"field of view must be in (0, 180) degrees, found {fov_deg}")
    focal = 0.5 * max(width, height) / math.tan(math.radians(fov_deg) / 2.0)
    return np.array([[focal, 0.0, (width - 1) / 2.0], [0.0, focal, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


def render_camera(camera: PinholeCamera, device: torch.device) -> Camera:
    """The rasterizer's camera (float32 tensors on ``device``) for ``camera``."""
    import torch

    from glimpse.render import Camera

    def tensor(a: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(np.asarray(a, dtype=np.float32), device=device)

    return Camera(tensor(camera.K), tensor(camera.R), tensor(camera.t), camera.width, camera.height)
