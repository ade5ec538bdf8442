"""The ControlNet's condition for an SDS view: the person's OpenPose-18 skeleton drawn from that camera.

The same drawing as stage 05's crops (glimpse.prior.skeleton): the body's 18 keypoints (SMPL joints
and face points, glimpse.body keypoint map) projected by the SDS camera; face points turned away
from the camera and points behind it are left out (GTU_REFERENCE.md 4, "ControlNet condition").
"""

from __future__ import annotations

import numpy as np

from glimpse.cameras.model import PinholeCamera
from glimpse.prior.skeleton import draw_skeleton, hidden_face, shown_keypoints


def skeleton_image(keypoints: np.ndarray, head: np.ndarray, camera: PinholeCamera, size: int,
                   line_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """keypoints [18, 3] and the head joint [3] in the camera's world (the body frame) -> (image [S, S, 3]
    uint8, pixels [18, 2], shown [18] bool) for a square camera of ``size`` pixels; ``line_px`` the limbs'
    half-width."""
    pixels, depth = camera.project(keypoints)
    shown = shown_keypoints(pixels, depth, hidden_face(keypoints, head, camera.centre), size)
    return draw_skeleton(pixels, shown, size, line_px), pixels, shown
