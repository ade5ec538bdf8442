"""Between the browser's camera (viser: camera-to-world rotation as a wxyz quaternion, OpenCV axes, the
camera's position, vertical field of view, canvas size) and Glimpse's pinhole cameras (world-to-camera R, t;
K with pixel centres at integers). Pure functions of arrays."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from glimpse.cameras.model import PinholeCamera


def render_size(canvas_width: int, canvas_height: int, max_side: int) -> tuple[int, int]:
    """(width, height) of a render with the canvas's aspect ratio and its longer side at most ``max_side``."""
    scale = min(1.0, max_side / max(canvas_width, canvas_height, 1))
    return max(1, round(canvas_width * scale)), max(1, round(canvas_height * scale))


def pinhole_from_viewer(wxyz: np.ndarray, position: np.ndarray, fov_y: float, width: int, height: int
                        ) -> PinholeCamera:
    """The browser's camera as a PinholeCamera of ``width`` x ``height`` pixels (square pixels, centred
    principal point). wxyz: (4,) camera-to-world rotation; position: (3,) world; fov_y: radians."""
    w, x, y, z = np.asarray(wxyz, float)
    camera_to_world = Rotation.from_quat([x, y, z, w]).as_matrix()
    R = camera_to_world.T
    focal = 0.5 * height / math.tan(0.5 * fov_y)
    K = np.array([[focal, 0.0, (width - 1) / 2.0], [0.0, focal, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
    return PinholeCamera(K, R, -R @ np.asarray(position, float), width, height)


def viewer_from_pinhole(camera: PinholeCamera) -> tuple[np.ndarray, np.ndarray, float]:
    """(wxyz, position, vertical field of view in radians) of the browser camera that sees what ``camera``
    sees (its principal point taken as centred)."""
    x, y, z, w = Rotation.from_matrix(camera.R.T).as_quat()
    fov_y = 2.0 * math.atan(0.5 * camera.height / camera.K[1, 1])
    return np.array([w, x, y, z]), camera.centre, fov_y
