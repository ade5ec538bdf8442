"""``load_scene``: validate a scene folder, then read it into a :class:`~glimpse.scene.model.Scene`.

The reader trusts the validator: once a scene has no violations, every entry
of its folders is well named and every JSON/YAML value has the right type, so
reading is a plain walk.  Frame ids and the frame size come from the
validation pass (frames are decoded once).
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np

from glimpse.errors import SceneError
from glimpse.io.images import parse_frame_name
from glimpse.scene.model import CameraPose, EvalCamera, HumanInputs, InputCameras, Scene
from glimpse.scene.validate import inspect_scene

__all__ = ["load_scene"]


def load_scene(root: str | Path, checked: bool = False) -> Scene:
    """Validate ``root`` and read it.

    Raises :class:`~glimpse.errors.SceneError` listing every violation when the
    folder breaks ``glimpse-scene/1``.  Paths in the result are absolute.
    ``checked``: the caller has validated this folder as it is now (a pipeline stage: its run validates the
    scene, cached by file, before the stage starts), so images are read by their headers, not decoded again.
    """
    root = Path(root).absolute()
    facts = inspect_scene(root, decode_images=not checked)
    if facts.violations:
        raise SceneError(str(root), facts.violations)
    assert facts.scene_yaml is not None and facts.frame_ids is not None and facts.frame_size is not None
    doc = facts.scene_yaml
    return Scene(
        root=root,
        name=doc["name"],
        fps=float(doc["fps"]),
        camera_motion=doc.get("camera_motion", "unknown"),
        body_model=doc.get("body_model", "free"),
        overrides=copy.deepcopy(doc.get("overrides") or {}),
        frame_ids=sorted(facts.frame_ids),
        frame_paths=dict(facts.frame_paths) if facts.video_path is None else {},
        video_path=facts.video_path,
        width=facts.frame_size[0],
        height=facts.frame_size[1],
        cameras=_read_input_cameras(root / "cameras.json"),
        humans=_read_humans(root / "humans"),
        eval_cameras=_read_eval_cameras(root / "eval"),
    )


def _array(value: object) -> np.ndarray:
    """A read-only float64 array (the model is immutable)."""
    array = np.array(value, dtype=np.float64)
    array.flags.writeable = False
    return array


def _poses(frames: dict) -> dict[int, CameraPose]:
    """``{"000003": {"R", "t"(, "K")}}`` -> ``{3: CameraPose}``, sorted by frame id."""
    poses = {parse_frame_name(key): CameraPose(R=_array(entry["R"]), t=_array(entry["t"]),
                                               K=_array(entry["K"]) if "K" in entry else None)
             for key, entry in frames.items()}
    return dict(sorted(poses.items()))  # type: ignore[arg-type]


def _read_input_cameras(path: Path) -> InputCameras | None:
    if not path.exists():
        return None
    doc = json.loads(path.read_text(encoding="utf-8"))
    return InputCameras(width=doc["width"], height=doc["height"], K=_array(doc["K"]),
                        dist=_array(doc["dist"]) if "dist" in doc else None,
                        poses=_poses(doc.get("frames", {})))


def _frame_files(folder: Path, suffixes: tuple[str, ...]) -> dict[int, Path]:
    """Frame id -> file for the ``<id><suffix>`` files of ``folder`` (empty when it does not exist)."""
    if not folder.is_dir():
        return {}
    files = {parse_frame_name(p.stem): p for p in sorted(folder.iterdir()) if p.is_file() and p.suffix in suffixes}
    return {i: p for i, p in sorted(files.items()) if i is not None}  # type: ignore[misc]


def _optional(path: Path) -> Path | None:
    return path if path.is_file() else None


def _read_humans(folder: Path) -> dict[str, HumanInputs]:
    if not folder.is_dir():
        return {}
    humans = {}
    for person in sorted(p for p in folder.iterdir() if p.is_dir()):
        reference = person / "reference"
        humans[person.name] = HumanInputs(
            pid=person.name,
            smpl=_optional(person / "smpl.npz"),
            keypoints2d=_optional(person / "keypoints2d.npz"),
            keypoints3d=_optional(person / "keypoints3d.npz"),
            masks=_frame_files(person / "masks", (".png",)),
            references=sorted(reference.iterdir()) if reference.is_dir() else [],
        )
    return humans


def _read_eval_cameras(folder: Path) -> dict[str, EvalCamera]:
    if not folder.is_dir():
        return {}
    doc = json.loads((folder / "cameras.json").read_text(encoding="utf-8"))
    cameras = {}
    for name, entry in sorted(doc["cameras"].items()):
        masks = folder / name / "masks"
        person_masks = {p.name: _frame_files(p, (".png",))
                        for p in sorted(masks.iterdir()) if p.is_dir()} if masks.is_dir() else {}
        cameras[name] = EvalCamera(
            name=name, width=entry["width"], height=entry["height"],
            K=_array(entry["K"]), R=_array(entry["R"]), t=_array(entry["t"]),
            poses=_poses(entry.get("frames", {})),
            images=_frame_files(folder / name, (".png", ".jpg", ".jpeg")),
            union_masks=_frame_files(masks, (".png",)),
            person_masks=person_masks,
        )
    return cameras
