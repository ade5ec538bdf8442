"""Which side of a person a camera sees, and the crop's prompt.

The body's canonical frame: +y up, +z the facing direction, +x the body's left (SMPL). The
azimuth is the angle, about the body's up, from its facing direction to the direction from the
pelvis to the camera centre, both projected onto the plane orthogonal to the up: 0 = the camera
straight in front, +90 = on the body's left, -90 = on its right, +-180 = behind.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

CANONICAL_FACING = np.array([0.0, 0.0, 1.0])
CANONICAL_UP = np.array([0.0, 1.0, 0.0])
VIEWS = ("front", "side", "back")
DEGENERATE_FRACTION = 1e-9  # a camera whose direction leaves less than this in the plane is straight above
TOKEN_TEMPLATE = "<person-{pid}>"  # the person's placeholder token: <person-p0> for pid p0


def facing_azimuth_deg(global_orient: np.ndarray, pelvis: np.ndarray, camera_centre: np.ndarray) -> float:
    """global_orient [3] axis-angle (radians, the root rotation), pelvis [3] and camera_centre [3]
    (world) -> the signed azimuth of the camera around the body, degrees in (-180, 180]. A camera
    straight above or below the pelvis (no direction left in the plane) gives 0."""
    rotation = Rotation.from_rotvec(np.asarray(global_orient, dtype=np.float64)).as_matrix()
    up, facing = rotation @ CANONICAL_UP, rotation @ CANONICAL_FACING
    to_camera = np.asarray(camera_centre, dtype=np.float64) - np.asarray(pelvis, dtype=np.float64)
    in_plane = to_camera - (to_camera @ up) * up  # facing is already orthogonal to up
    if np.linalg.norm(in_plane) <= DEGENERATE_FRACTION * np.linalg.norm(to_camera):
        return 0.0
    return float(math.degrees(math.atan2(float(up @ np.cross(facing, in_plane)), float(facing @ in_plane))))


def view_word(azimuth_deg: float, front_max_deg: float, back_min_deg: float) -> str:
    """|azimuth| below front_max_deg: "front"; above back_min_deg: "back"; else "side"."""
    angle = abs(azimuth_deg)
    if angle < front_max_deg:
        return "front"
    if angle > back_min_deg:
        return "back"
    return "side"


def person_token(pid: str) -> str:
    """The placeholder token of a person in prompts (and, with the sds prior, its learnt embedding)."""
    return TOKEN_TEMPLATE.format(pid=pid)


def view_prompt(template: str, pid: str, view: str) -> str:
    """pipeline.yaml's prompt_template with {token} and {view} filled in."""
    return template.format(token=person_token(pid), view=view)
