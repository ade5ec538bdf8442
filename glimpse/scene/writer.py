"""Writing a ``glimpse-scene/1`` folder (docs/SCENE_FORMAT.md): what :func:`glimpse.scene.load_scene` reads.

    writer = SceneWriter(root, name="hallway", fps=30, camera_motion="static", body_model="free")
    writer.frame(0, rgb)                                   # one frame at a time: nothing is held in memory
    writer.input_cameras(width, height, K, poses={0: CameraPose(R, t)})
    writer.person_mask("p0", 0, mask)
    writer.smpl("p0", frame_ids, betas, global_orient, body_pose, transl)
    writer.eval_camera("cam0", width, height, K, R, t)
    writer.eval_view("cam0", 0, rgb, union_mask, {"p0": mask})
    writer.finish()                                        # validated, then renamed into place

Everything is written into a staging folder beside ``root`` and renamed to ``root`` by ``finish``, which first
validates the staged scene and refuses (SceneError, the staging folder kept for inspection) one that breaks the
format. Arrays follow the reader's conventions: images [H, W, 3] uint8, masks [H, W] bool, extrinsics world to
camera, metres.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from glimpse.errors import GlimpseError, SceneError
from glimpse.io.images import frame_name, write_png
from glimpse.scene.model import (
    CAMERAS_FORMAT, EVAL_CAMERAS_FORMAT, KEYPOINT_LAYOUTS, SCENE_FORMAT_VERSION, CameraPose,
)

JSON_INDENT = 1
MASK_ON = 255  # a mask pixel that is set (the format's masks are 0 / 255)


def _matrix(array: np.ndarray) -> list:
    return np.asarray(array, dtype=np.float64).tolist()


def _pose(pose: CameraPose) -> dict[str, Any]:
    doc = {"R": _matrix(pose.R), "t": _matrix(pose.t)}
    if pose.K is not None:
        doc["K"] = _matrix(pose.K)
    return doc


def _mask_png(mask: np.ndarray) -> np.ndarray:
    return np.asarray(mask, dtype=bool).astype(np.uint8) * MASK_ON


def scene_folder(root: Path) -> Path:
    """The folder a scene for ``root`` is written to: ``root`` itself, or the folder it links to (the link stays;
    a scene folder kept on another disk). Refuses, before anything is computed, a ``root`` that is a file or a
    link to one, which the finished scene could not replace."""
    root = Path(root)
    folder = root.resolve() if root.is_symlink() else root
    if folder.exists() and not folder.is_dir():
        raise GlimpseError(f"{root}: exists and is not a folder; the scene is written as a folder there: give "
                           "another path, or move the file away")
    return folder


class SceneWriter:
    """Writes one scene folder, part by part (see the module docstring)."""

    def __init__(self, root: Path, name: str, fps: float, camera_motion: str = "unknown",
                 body_model: str | None = None, overrides: dict[str, dict] | None = None):
        self.root = scene_folder(root)
        self.staging = self.root.with_name(self.root.name + ".tmp")
        shutil.rmtree(self.staging, ignore_errors=True)
        self.staging.mkdir(parents=True)
        self.scene_yaml: dict[str, Any] = {"format": SCENE_FORMAT_VERSION, "name": name, "fps": fps,
                                           "camera_motion": camera_motion}
        if body_model is not None:
            self.scene_yaml["body_model"] = body_model
        if overrides:
            self.scene_yaml["overrides"] = overrides
        self.eval_cameras: dict[str, dict[str, Any]] = {}

    def _png(self, relative: str, pixels: np.ndarray) -> None:
        path = self.staging / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        write_png(path, pixels)

    def _json(self, relative: str, doc: dict) -> None:
        path = self.staging / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(doc, indent=JSON_INDENT))

    # --- the input video -------------------------------------------------------------------------

    def frame(self, frame_id: int, rgb: np.ndarray) -> None:
        """frames/<id>.png from ``rgb`` [H, W, 3] uint8."""
        self._png(f"frames/{frame_name(frame_id)}.png", rgb)

    def input_cameras(self, width: int, height: int, K: np.ndarray, dist: np.ndarray | None = None,
                      poses: dict[int, CameraPose] | None = None) -> None:
        """cameras.json: the shared intrinsics K [3, 3] (OpenCV pixel centres), optional distortion, and per-frame
        world-to-camera poses (none: a static camera whose frame is the world frame)."""
        doc: dict[str, Any] = {"format": CAMERAS_FORMAT, "width": int(width), "height": int(height), "K": _matrix(K)}
        if dist is not None:
            doc["dist"] = _matrix(dist)
        if poses:
            doc["frames"] = {frame_name(fid): _pose(pose) for fid, pose in sorted(poses.items())}
        self._json("cameras.json", doc)

    # --- people --------------------------------------------------------------------------------------

    def person_mask(self, pid: str, frame_id: int, mask: np.ndarray) -> None:
        """humans/<pid>/masks/<id>.png: the person's visible region ``mask`` [H, W] bool."""
        self._png(f"humans/{pid}/masks/{frame_name(frame_id)}.png", _mask_png(mask))

    def smpl(self, pid: str, frame_ids: np.ndarray, betas: np.ndarray, global_orient: np.ndarray,
             body_pose: np.ndarray, transl: np.ndarray) -> None:
        """humans/<pid>/smpl.npz: betas [10], global_orient [T, 3], body_pose [T, 69], transl [T, 3] (metres)."""
        folder = self.staging / "humans" / pid
        folder.mkdir(parents=True, exist_ok=True)
        np.savez(folder / "smpl.npz", frame_ids=np.asarray(frame_ids), betas=betas, global_orient=global_orient,
                 body_pose=body_pose, transl=transl)

    def keypoints2d(self, pid: str, frame_ids: np.ndarray, layout: str, keypoints: np.ndarray,
                    relative3d: np.ndarray | None = None) -> None:
        """humans/<pid>/keypoints2d.npz: keypoints [T, J, 3] (pixel x, y, confidence) in ``layout``; optionally
        relative3d [T, J, 4] (metres from the mid hip in the image's axes, confidence: SCENE_FORMAT.md)."""
        extra = {} if relative3d is None else {"relative3d": relative3d}
        self._keypoints(pid, "keypoints2d.npz", frame_ids, layout, keypoints=keypoints, **extra)

    def keypoints3d(self, pid: str, frame_ids: np.ndarray, layout: str, joints: np.ndarray) -> None:
        """humans/<pid>/keypoints3d.npz: joints [T, J, 4] (world x, y, z in metres, confidence) in ``layout``."""
        self._keypoints(pid, "keypoints3d.npz", frame_ids, layout, joints=joints)

    def _keypoints(self, pid: str, file: str, frame_ids: np.ndarray, layout: str, **array: np.ndarray) -> None:
        if layout not in KEYPOINT_LAYOUTS:
            raise ValueError(f"keypoint layout {layout!r}: the format knows {', '.join(KEYPOINT_LAYOUTS)}")
        folder = self.staging / "humans" / pid
        folder.mkdir(parents=True, exist_ok=True)
        np.savez(folder / file, frame_ids=np.asarray(frame_ids), layout=np.array(layout), **array)

    def reference(self, pid: str, name: str, rgb: np.ndarray) -> None:
        """humans/<pid>/reference/<name>.png: another photo of the person (the identity prior's)."""
        self._png(f"humans/{pid}/reference/{name}.png", rgb)

    # --- held-out views ------------------------------------------------------------------------------

    def eval_camera(self, name: str, width: int, height: int, K: np.ndarray, R: np.ndarray, t: np.ndarray,
                    poses: dict[int, CameraPose] | None = None) -> None:
        """A held-out camera of eval/cameras.json: its static pose, and per-frame poses where it moves."""
        doc: dict[str, Any] = {"K": _matrix(K), "R": _matrix(R), "t": _matrix(t), "width": int(width),
                               "height": int(height)}
        if poses:
            doc["frames"] = {frame_name(fid): _pose(pose) for fid, pose in sorted(poses.items())}
        self.eval_cameras[name] = doc

    def eval_view(self, camera: str, frame_id: int, rgb: np.ndarray, union_mask: np.ndarray | None = None,
                  person_masks: dict[str, np.ndarray] | None = None) -> None:
        """eval/<camera>/<id>.png, its union mask of every person (None: a camera without masks, scored on the
        full frame only; then give none for its other views either) and, optionally, each person's mask."""
        self._png(f"eval/{camera}/{frame_name(frame_id)}.png", rgb)
        if union_mask is not None:
            self._png(f"eval/{camera}/masks/{frame_name(frame_id)}.png", _mask_png(union_mask))
        for pid, mask in (person_masks or {}).items():
            self._png(f"eval/{camera}/masks/{pid}/{frame_name(frame_id)}.png", _mask_png(mask))

    def written(self, relative: str) -> Path:
        """The staged path of a file this writer has written (``frames/000042.png``), to read it back before
        :meth:`finish`."""
        path = self.staging / relative
        if not path.is_file():
            raise FileNotFoundError(f"{relative} has not been written to {self.staging}")
        return path

    def side_file(self, relative: str) -> Path:
        """A path inside the staged scene for a file the format does not name (a report, a preview): it moves
        into place with the scene, and readers ignore it. Its folder is created."""
        path = self.staging / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        return path

    # --- the end -------------------------------------------------------------------------------------

    def finish(self, validate: bool = True) -> Path:
        """Write scene.yaml (and eval/cameras.json), validate the staged folder, and rename it to ``root``
        (replacing a previous scene there). A scene that breaks the format is refused with every problem named;
        the staging folder stays for inspection."""
        if self.eval_cameras:
            self._json("eval/cameras.json", {"format": EVAL_CAMERAS_FORMAT, "cameras": self.eval_cameras})
        (self.staging / "scene.yaml").write_text(yaml.safe_dump(self.scene_yaml, sort_keys=False))
        if validate:
            from glimpse.scene.validate import validate_scene

            violations = validate_scene(self.staging)
            if violations:
                raise SceneError(str(self.staging), violations)
        shutil.rmtree(self.root, ignore_errors=True)
        self.staging.rename(self.root)
        return self.root
