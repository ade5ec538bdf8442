"""Writes tiny, VALID ``glimpse-scene/1`` folders for tests, plus small editing helpers.

``build_valid_scene(root)`` writes, with glimpse.scene's writer: scene.yaml, frames/000000..000002.png (16x12),
cameras.json with per-frame poses (frame 1 with its own K), humans/p0 and
humans/p1 (smpl.npz, keypoints2d.npz, keypoints3d.npz, masks/, reference/), and
eval/ with one held-out camera ``cam1`` (20x10 images, union masks, p0's masks).
Tests copy it and break one thing at a time.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import yaml
from PIL import Image

from glimpse.scene.model import CameraPose
from glimpse.scene.writer import SceneWriter

WIDTH, HEIGHT = 16, 12
EVAL_WIDTH, EVAL_HEIGHT = 20, 10
PERSONS = ("p0", "p1")


def rotation_y(angle: float) -> np.ndarray:
    """(3, 3) rotation about the y axis by ``angle`` radians."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def intrinsics(width: int, height: int, f: float = 20.0) -> list[list[float]]:
    """A pinhole K as JSON lists, principal point at the image centre."""
    return [[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]]


# --- writing ----------------------------------------------------------------------------------

def write_image(path: Path, pixels: np.ndarray, **save_args: object) -> Path:
    """Write a uint8 (H, W) / (H, W, C) array with Pillow (format from the suffix)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.asarray(pixels)).save(path, **save_args)
    return path


def rgb(width: int, height: int, seed: int = 0) -> np.ndarray:
    """A deterministic (H, W, 3) uint8 test picture."""
    return np.random.default_rng(seed).integers(0, 256, (height, width, 3), dtype=np.uint8)


def mask(width: int, height: int, seed: int = 0) -> np.ndarray:
    """A (H, W) uint8 0/255 mask: a box whose position depends on ``seed``."""
    m = np.zeros((height, width), np.uint8)
    m[2 + seed % 3: height - 2, 3: width - 3 - seed % 2] = 255
    return m


def write_yaml(path: Path, doc: object) -> None:
    path.write_text(yaml.safe_dump(doc, sort_keys=False))


def read_yaml(path: Path) -> dict:
    return yaml.safe_load(path.read_text())


def write_json(path: Path, doc: object) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc, indent=1))


def read_json(path: Path) -> dict:
    return json.loads(path.read_text())


def edit_yaml(path: Path, edit: Callable[[dict], None]) -> None:
    """Apply ``edit`` to the parsed YAML mapping in place and write it back."""
    doc = read_yaml(path)
    edit(doc)
    write_yaml(path, doc)


def edit_json(path: Path, edit: Callable[[dict], None]) -> None:
    """Apply ``edit`` to the parsed JSON object in place and write it back."""
    doc = read_json(path)
    edit(doc)
    write_json(path, doc)


def edit_npz(path: Path, **changes: object) -> None:
    """Replace arrays of an .npz file; a value of None deletes the key."""
    with np.load(path, allow_pickle=False) as data:
        arrays = {key: data[key] for key in data.files}
    for key, value in changes.items():
        if value is None:
            arrays.pop(key, None)
        else:
            arrays[key] = value
    np.savez(path, **arrays)


# --- the valid scene ----------------------------------------------------------------------------

def build_valid_scene(root: Path, *, n_frames: int = 3, width: int = WIDTH, height: int = HEIGHT) -> Path:
    """Write a complete valid scene at ``root`` (with glimpse.scene's writer, which validates it) and return
    ``root``."""
    ids = list(range(n_frames))
    scene = SceneWriter(root, "tiny_scene", 10, "moving", "smpl", overrides={"04_bg_pretrain": {"iterations": 10}})
    for i in ids:
        scene.frame(i, rgb(width, height, seed=i))
    poses = {i: CameraPose(rotation_y(0.05 * i), np.array([0.0, 0.0, 3.0])) for i in ids}
    poses[ids[-1]] = CameraPose(poses[ids[-1]].R, poses[ids[-1]].t, np.array(intrinsics(width, height, f=25.0)))
    scene.input_cameras(width, height, np.array(intrinsics(width, height)), np.array([0.01, 0.0, 0.0, 0.0]), poses)
    for n, pid in enumerate(PERSONS):
        _write_person(scene, pid, ids, width, height, seed=n)
    eval_pose = CameraPose(rotation_y(0.5), np.array([0.2, 0.0, 3.0]))
    scene.eval_camera("cam1", EVAL_WIDTH, EVAL_HEIGHT, np.array(intrinsics(EVAL_WIDTH, EVAL_HEIGHT)), eval_pose.R,
                      eval_pose.t, poses={0: eval_pose})
    for i in ids:
        union = mask(EVAL_WIDTH, EVAL_HEIGHT, seed=i) > 0
        scene.eval_view("cam1", i, rgb(EVAL_WIDTH, EVAL_HEIGHT, seed=10 + i), union, {"p0": union})
    return scene.finish()


def _write_person(scene: SceneWriter, pid: str, ids: list[int], width: int, height: int, seed: int) -> None:
    T = len(ids)
    frame_ids = np.array(ids, dtype=np.int64)
    scene.smpl(pid, frame_ids, np.zeros(10), np.zeros((T, 3)), np.zeros((T, 69)), np.tile([0.3 * seed, 0.0, 0.0], (T, 1)))
    keypoints = np.zeros((T, 17, 3))
    keypoints[..., 0], keypoints[..., 1], keypoints[..., 2] = width / 2, height / 2, 0.9
    scene.keypoints2d(pid, frame_ids, "coco17", keypoints)
    joints = np.zeros((T, 25, 4))
    joints[..., 3] = 1.0
    scene.keypoints3d(pid, frame_ids, "openpose25", joints)
    for i in ids:
        scene.person_mask(pid, i, mask(width, height, seed=i + seed) > 0)
    scene.reference(pid, "front", rgb(8, 8, seed=seed))
