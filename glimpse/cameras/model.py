"""The camera record shared by every stage (OpenCV pinhole, world-to-camera) and its conversion to the
rasterizer's camera."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from glimpse.render import Camera


@dataclass(frozen=True)
class PinholeCamera:
    """One frame's camera.

    K: (3, 3) intrinsics; the centre of the top-left pixel is at (0, 0) (OpenCV).
    R: (3, 3) world-to-camera rotation; t: (3,) translation: x_cam = R @ x_world + t.
    """

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray

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


def default_intrinsics(width: int, height: int, fov_deg: float) -> np.ndarray:
    """(3, 3) K with the given field of view across the larger image side, centred.

    The principal point is the image centre in OpenCV's convention: ((W-1)/2, (H-1)/2).
    """
    if not 0.0 < fov_deg < 180.0:
        raise ValueError(f"field of view must be in (0, 180) degrees, found {fov_deg}")
    focal = 0.5 * max(width, height) / math.tan(math.radians(fov_deg) / 2.0)
    return np.array([[focal, 0.0, (width - 1) / 2.0], [0.0, focal, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


def render_camera(camera: PinholeCamera, width: int, height: int, device: torch.device) -> Camera:
    """The rasterizer's camera (float32 tensors on ``device``) for ``camera`` at an image of width x height."""
    def tensor(a: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(np.asarray(a, dtype=np.float32), device=device)

    return Camera(tensor(camera.K), tensor(camera.R), tensor(camera.t), width, height)
