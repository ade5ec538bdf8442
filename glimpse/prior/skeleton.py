"""OpenPose-18 skeleton images (the pose condition of ControlNet's openpose model): which keypoints a
crop shows, and drawing them.

Keypoint order: glimpse.body.keypoints LAYOUTS["openpose18"] (0 nose, 1 neck, 2-4 right
shoulder/elbow/wrist, 5-7 left, 8-10 right hip/knee/ankle, 11-13 left, 14/15 right/left eye,
16/17 right/left ear).

Drawing convention: controlnet_aux's ``draw_bodypose`` (the OpenPose body demo's ``util.py``, as
ControlNet's openpose annotator draws): on black RGB, the first 17 of OpenPose's 19 limb pairs,
each a filled ellipse along the limb with half-width ``stickwidth`` in 0.6 times the limb's colour,
then every keypoint as a filled disk of the same radius in its own full colour (18 colours, red
through the hues to magenta), keypoints drawn in order over the limbs. Coordinates are drawn with
sub-pixel precision (OpenPose truncates to whole pixels).
"""

from __future__ import annotations

import cv2
import numpy as np

from glimpse.body.keypoints import LAYOUTS

OPENPOSE18_NAMES: tuple[str, ...] = tuple(name for name, _ in LAYOUTS["openpose18"])
# limb pairs (0-based) in OpenPose's order; its two last pairs (shoulder-ear) are never drawn
OPENPOSE18_LIMBS: tuple[tuple[int, int], ...] = (
    (1, 2), (1, 5), (2, 3), (3, 4), (5, 6), (6, 7), (1, 8), (8, 9), (9, 10), (1, 11), (11, 12), (12, 13),
    (1, 0), (0, 14), (14, 16), (0, 15), (15, 17),
)
# RGB, one per keypoint; limb k is drawn in colour k times LIMB_SHADE
OPENPOSE18_COLOURS: tuple[tuple[int, int, int], ...] = (
    (255, 0, 0), (255, 85, 0), (255, 170, 0), (255, 255, 0), (170, 255, 0), (85, 255, 0), (0, 255, 0),
    (0, 255, 85), (0, 255, 170), (0, 255, 255), (0, 170, 255), (0, 85, 255), (0, 0, 255), (85, 0, 255),
    (170, 0, 255), (255, 0, 255), (255, 0, 170), (255, 0, 85),
)
LIMB_SHADE = 0.6
FACE_NAMES = ("nose", "right_eye", "left_eye", "right_ear", "left_ear")
FACE_KEYPOINTS: tuple[int, ...] = tuple(OPENPOSE18_NAMES.index(name) for name in FACE_NAMES)
HEAD_JOINT = 15  # SMPL's head joint, about the centre of the head
# degrees: a face keypoint is hidden when it lies more than this behind the plane through the head
# joint facing the camera (seen from the head joint); 0 would make the nose of an exact profile flicker
FACE_BEHIND_TOLERANCE_DEG = 10.0
NEAR_DEPTH = 1e-3  # world units: keypoints nearer the camera plane than this (or behind it) are dropped
OFF_CROP_FRACTION = 0.25  # keypoints farther than this fraction of the crop's side outside it are dropped
ELLIPSE_STEP_DEG = 1  # the limb ellipse's polygon, a vertex per degree (cv2.ellipse2Poly's delta)
SUBPIXEL_BITS = 4  # cv2 drawing with fractional coordinates: 1/16 pixel


def hidden_face(keypoints: np.ndarray, head: np.ndarray, camera_centre: np.ndarray) -> np.ndarray:
    """keypoints [18, 3], head [3] (SMPL joint 15), camera_centre [3], world -> [18] bool: face
    keypoints (nose, eyes, ears) farther from the camera than the head joint along the line of
    sight to it, by more than FACE_BEHIND_TOLERANCE_DEG seen from the head joint: the face turned
    away (nose and eyes seen from behind, the far eye and ear in profile; the ears, about level with
    the head joint, stay from behind). Other keypoints: False."""
    sight = np.asarray(camera_centre, dtype=np.float64) - head
    sight = sight / max(float(np.linalg.norm(sight)), np.finfo(float).tiny)
    offsets = keypoints - head
    toward_camera = offsets @ sight  # > 0: nearer the camera than the head joint
    behind = -np.sin(np.radians(FACE_BEHIND_TOLERANCE_DEG)) * np.linalg.norm(offsets, axis=1)
    hidden = np.zeros(len(keypoints), bool)
    face = list(FACE_KEYPOINTS)
    hidden[face] = toward_camera[face] < behind[face]
    return hidden


def shown_keypoints(pixels: np.ndarray, depth: np.ndarray, hidden: np.ndarray, size: int) -> np.ndarray:
    """pixels [18, 2] (crop pixels), depth [18] (along the optical axis), hidden [18] -> [18] bool:
    in front of the camera, not a hidden face point, and within OFF_CROP_FRACTION of the crop."""
    margin = OFF_CROP_FRACTION * size
    finite = np.isfinite(pixels).all(1)
    with np.errstate(invalid="ignore"):
        near = ((pixels >= -margin) & (pixels <= size - 1 + margin)).all(1)
    return (depth > NEAR_DEPTH) & finite & near & ~hidden


def _fixed(points: np.ndarray) -> np.ndarray:
    return np.rint(np.asarray(points, dtype=np.float64) * (1 << SUBPIXEL_BITS)).astype(np.int32)


def limb_polygon(a: np.ndarray, b: np.ndarray, half_width: float) -> np.ndarray:
    """[P, 2] float: the ellipse OpenPose draws for the limb from a [2] to b [2] (pixels)."""
    centre, along = (a + b) / 2.0, b - a
    length = float(np.hypot(*along))
    direction = along / length if length > 0 else np.array([1.0, 0.0])
    normal = np.array([-direction[1], direction[0]])
    t = np.radians(np.arange(0, 360 + ELLIPSE_STEP_DEG, ELLIPSE_STEP_DEG))
    return centre + np.outer(length / 2.0 * np.cos(t), direction) + np.outer(half_width * np.sin(t), normal)


def draw_skeleton(pixels: np.ndarray, shown: np.ndarray, size: int, line_px: float) -> np.ndarray:
    """pixels [18, 2] crop pixels, shown [18] bool -> [size, size, 3] uint8 RGB OpenPose drawing:
    limbs whose two ends are shown, then the shown keypoints (disks of radius ``line_px``)."""
    canvas = np.zeros((size, size, 3), np.uint8)
    for (i, j), colour in zip(OPENPOSE18_LIMBS, OPENPOSE18_COLOURS):
        if shown[i] and shown[j]:
            shade = tuple(int(c * LIMB_SHADE) for c in colour)
            cv2.fillConvexPoly(canvas, _fixed(limb_polygon(pixels[i], pixels[j], line_px)), shade,
                               lineType=cv2.LINE_8, shift=SUBPIXEL_BITS)
    radius = int(_fixed(line_px))
    for k, colour in enumerate(OPENPOSE18_COLOURS):
        if shown[k]:
            cv2.circle(canvas, tuple(int(v) for v in _fixed(pixels[k])), radius, colour, thickness=-1,
                       lineType=cv2.LINE_8, shift=SUBPIXEL_BITS)
    return canvas
