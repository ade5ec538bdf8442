"""The scene input contract ``glimpse-scene/1``: validation, reading and writing.

``validate_scene(root)`` lists every violation of a scene folder;
``load_scene(root)`` validates, raises :class:`~glimpse.errors.SceneError` when
anything is wrong, and returns a :class:`Scene`; :class:`SceneWriter` writes a
scene part by part (the fixtures, the tests' scenes, importers).  The contract
itself is docs/SCENE_FORMAT.md.
"""

from glimpse.scene.model import (
    CAMERAS_FORMAT,
    EVAL_CAMERAS_FORMAT,
    KEYPOINT_LAYOUTS,
    SCENE_FORMAT_VERSION,
    CameraPose,
    EvalCamera,
    HumanInputs,
    InputCameras,
    Keypoints2D,
    Keypoints3D,
    Scene,
    read_keypoints2d,
    read_keypoints3d,
)
from glimpse.scene.reader import load_scene
from glimpse.scene.validate import validate_scene
from glimpse.scene.writer import SceneWriter

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
    "SceneWriter",
    "load_scene",
    "read_keypoints2d",
    "read_keypoints3d",
    "validate_scene",
]
