"""What a validated ``glimpse-scene/1`` folder holds, as immutable values.

All arrays are ``float64`` unless stated otherwise; lengths are in metres,
intrinsics in pixels (OpenCV convention: the centre of the top-left pixel is at
(0, 0)), extrinsics map world to camera: ``x_cam = R @ x_world + t``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from glimpse.cameras.model import PinholeCamera, camera_from_pose

__all__ = [
    "CAMERAS_FORMAT",
    "EVAL_CAMERAS_FORMAT",
    "KEYPOINT_LAYOUTS",
    "SCENE_FORMAT_VERSION",
    "CameraPose",
    "EvalCamera",
    "HumanInputs",
    "InputCameras",
    "Keypoints2D",
    "Keypoints3D",
    "Scene",
    "read_keypoints2d",
    "read_keypoints3d",
]

SCENE_FORMAT_VERSION = "glimpse-scene/1"
CAMERAS_FORMAT = "glimpse-cameras/1"
EVAL_CAMERAS_FORMAT = "glimpse-eval-cameras/1"
#: keypoint layout name -> number of joints J
KEYPOINT_LAYOUTS: dict[str, int] = {"coco17": 17, "openpose25": 25, "coco19": 19}


@dataclass(frozen=True)
class CameraPose:
    """One frame of a camera.

    R: (3, 3) world-to-camera rotation, ``x_cam = R @ x_world + t``.
    t: (3,) translation, metres.
    K: (3, 3) intrinsics of this frame (zoom), or None = the camera's shared K.
    """

    R: np.ndarray
    t: np.ndarray
    K: np.ndarray | None = None


@dataclass(frozen=True)
class InputCameras:
    """Contents of ``<scene>/cameras.json`` (the input camera).

    width, height: image size in pixels (equal to the frame size).
    K:     (3, 3) shared intrinsics.
    dist:  (4,) or (5,) OpenCV distortion ``[k1, k2, p1, p2(, k3)]``, or None.
    poses: frame id -> pose; EMPTY when the file has no ``"frames"`` (static
           camera, world frame = camera frame).
    """

    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray | None
    poses: dict[int, CameraPose] = field(default_factory=dict)


@dataclass(frozen=True)
class HumanInputs:
    """The files given for one person, ``<scene>/humans/<pid>/`` (absolute paths)."""

    pid: str
    smpl: Path | None
    keypoints2d: Path | None
    keypoints3d: Path | None
    masks: dict[int, Path]     # frame id -> mask PNG (may be empty)
    references: list[Path]     # reference photos, sorted by name


@dataclass(frozen=True)
class EvalCamera:
    """One held-out view of ``eval/cameras.json`` with its files (absolute paths).

    K, R, t: (3, 3), (3, 3), (3,) static intrinsics and world-to-camera pose.
    poses:   optional per-frame poses (frame id -> pose); empty = static.
    images:  frame id -> ground-truth image.
    union_masks:  frame id -> mask of all humans (same ids as ``images``), or empty: a camera without masks
                  (scored on the full frame only).
    person_masks: pid -> frame id -> mask of that person (optional, may be empty).
    """

    name: str
    width: int
    height: int
    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    poses: dict[int, CameraPose]
    images: dict[int, Path]
    union_masks: dict[int, Path]
    person_masks: dict[str, dict[int, Path]]

    def camera_at(self, frame_id: int) -> PinholeCamera:
        """The camera at ``frame_id``: its per-frame pose (and intrinsics) where given, else its one pose."""
        pose = self.poses.get(frame_id)
        if pose is None:
            return PinholeCamera(self.K, self.R, self.t, self.width, self.height)
        return camera_from_pose(self.K, pose.R, pose.t, self.width, self.height, pose.K)


@dataclass(frozen=True)
class Scene:
    """A validated scene folder.

    frame_ids:   sorted frame ids; for a video scene ``0 .. N-1``.
    frame_paths: frame id -> image in ``frames/``; EMPTY for a video scene.
    width, height: frame size in pixels.
    overrides:   stage/section name -> mapping of parameter overrides (the
                 config layer checks the keys and values).
    """

    root: Path
    name: str
    fps: float
    camera_motion: str          # "static" | "moving" | "unknown"
    body_model: str             # "free" | "smpl"
    overrides: dict
    frame_ids: list[int]
    frame_paths: dict[int, Path]
    video_path: Path | None
    width: int
    height: int
    cameras: InputCameras | None
    humans: dict[str, HumanInputs]
    eval_cameras: dict[str, EvalCamera]

    def has_3d_person_data(self) -> bool:
        """True when any person has ``smpl.npz`` or ``keypoints3d.npz``."""
        return any(h.smpl is not None or h.keypoints3d is not None for h in self.humans.values())


@dataclass(frozen=True)
class Keypoints2D:
    """Contents of ``keypoints2d.npz``.

    frame_ids: (T,) int64.
    layout:    a key of :data:`KEYPOINT_LAYOUTS`.
    keypoints: (T, J, 3) float64: pixel x, pixel y, confidence in [0, 1] (0 = missing).
    relative3d: (T, J, 4) float64 or None: metric 3D keypoints relative to the mid hip, in the image's axes
               (x right, y down, z away from the camera, as seen looking straight at the person), and
               confidence in [0, 1]; what a monocular 3D pose model (BlazePose's world landmarks) says.
    """

    frame_ids: np.ndarray
    layout: str
    keypoints: np.ndarray
    relative3d: np.ndarray | None = None


@dataclass(frozen=True)
class Keypoints3D:
    """Contents of ``keypoints3d.npz``.

    frame_ids: (T,) int64.
    layout:    a key of :data:`KEYPOINT_LAYOUTS`.
    joints:    (T, J, 4) float64: world x, y, z (metres), confidence in [0, 1].
    """

    frame_ids: np.ndarray
    layout: str
    joints: np.ndarray


RELATIVE3D_KEY = "relative3d"  # keypoints2d.npz's optional metric 3D keypoints (Keypoints2D.relative3d)


def _read_keypoints(path: str | Path, key: str, channels: int) -> tuple[np.ndarray, str, np.ndarray]:
    """Load ``frame_ids``, ``layout`` and the ``(T, J, channels)`` array ``key``.

    Raises ValueError when the file does not have that shape (run the scene
    validator for a full diagnosis).
    """
    with np.load(Path(path), allow_pickle=False) as npz:
        frame_ids = np.asarray(npz["frame_ids"]).astype(np.int64)
        layout = str(np.asarray(npz["layout"]).item())
        values = np.asarray(npz[key], dtype=np.float64)
    joints = KEYPOINT_LAYOUTS.get(layout)
    if joints is None or values.shape != (len(frame_ids), joints, channels):
        raise ValueError(f"{path}: expected {key} of shape (T, J, {channels}) for layout {layout!r}; "
                         f"got {values.shape}")
    return frame_ids, layout, values


def read_keypoints2d(path: str | Path) -> Keypoints2D:
    """Read a ``keypoints2d.npz`` file (see :class:`Keypoints2D`)."""
    frame_ids, layout, keypoints = _read_keypoints(path, "keypoints", 3)
    with np.load(Path(path), allow_pickle=False) as npz:
        relative3d = np.asarray(npz[RELATIVE3D_KEY], dtype=np.float64) if RELATIVE3D_KEY in npz.files else None
    if relative3d is not None and relative3d.shape != (*keypoints.shape[:2], 4):
        raise ValueError(f"{path}: expected {RELATIVE3D_KEY} of shape (T, J, 4); got {relative3d.shape}")
    return Keypoints2D(frame_ids, layout, keypoints, relative3d)


def read_keypoints3d(path: str | Path) -> Keypoints3D:
    """Read a ``keypoints3d.npz`` file (see :class:`Keypoints3D`)."""
    return Keypoints3D(*_read_keypoints(path, "joints", 4))
