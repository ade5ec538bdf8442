"""Rules of ``cameras.json`` (the input camera), and the JSON camera checks
that ``eval/cameras.json`` shares (intrinsics, rotations, per-frame poses)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from glimpse.io.images import parse_frame_name
from glimpse.scene._common import SceneFacts, describe, describe_range
from glimpse.scene.model import CAMERAS_FORMAT

CAMERAS_KEYS = ("format", "width", "height", "K", "dist", "frames")
POSE_KEYS = ("R", "t", "K")
ROTATION_TOL = 1e-4
EXACT_TOL = 1e-9


class _Bad(Exception):
    """A JSON value that is not the expected nest of numbers (message: what was found)."""


def _numbers(value: object, shape: tuple[int, ...], path: str) -> object:
    """``value`` as nested lists of floats of ``shape``; raises _Bad naming the first misfit."""
    if not shape:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise _Bad(f"{path} = {describe(value)}")
        try:
            return float(value)
        except OverflowError:
            raise _Bad(f"{path} = {value} (too large)") from None
    if not isinstance(value, list):
        raise _Bad(f"{path} = {describe(value)}")
    if len(value) != shape[0]:
        raise _Bad(f"{path} has {len(value)} entries")
    return [_numbers(item, shape[1:], f"{path}[{i}]") for i, item in enumerate(value)]


def parse_array(value: object, shape: tuple[int, ...], name: str) -> tuple[np.ndarray | None, str]:
    """Parse a JSON list nest into a finite float64 array of ``shape``.

    Returns ``(array, "")`` or ``(None, found)`` where ``found`` names the first
    entry that is missing, not a number, or not finite (e.g. ``"K[0][0] = NaN"``).
    """
    try:
        array = np.asarray(_numbers(value, shape, name), dtype=np.float64)
    except _Bad as bad:
        return None, str(bad)
    if not np.all(np.isfinite(array)):
        index = tuple(int(i) for i in np.argwhere(~np.isfinite(array))[0])
        where = name + "".join(f"[{i}]" for i in index)
        return None, f"{where} = {describe(float(array[index]))}"
    return array, ""


def load_json(facts: SceneFacts, path: Path) -> object | None:
    """Parse a JSON file; None (and a violation) when it cannot be read or parsed."""
    rel = path.relative_to(facts.root).as_posix()
    if path.is_dir():
        facts.add(rel, f"{rel} must be a JSON file", "a folder")
        return None
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        facts.add(rel, f"{rel} must be a readable UTF-8 JSON file", str(err))
        return None
    try:
        return json.loads(text)
    except json.JSONDecodeError as err:
        facts.add(rel, f"{rel} must be valid JSON", f"{err.msg} at line {err.lineno} column {err.colno}")
        return None


@dataclass
class CameraChecks:
    """Checks of camera values inside one JSON file (``file``: its relative path)."""

    facts: SceneFacts
    file: str

    def add(self, rule: str, found: str) -> None:
        self.facts.add(self.file, rule, found)

    def format(self, doc: dict, expected: str) -> None:
        """``doc["format"]`` must equal ``expected``."""
        if "format" not in doc:
            self.add(f'format must be "{expected}"', 'no "format" key')
        elif doc["format"] != expected:
            self.add(f'format must be "{expected}"', f"{describe(doc['format'])} (known formats: {expected})")

    def keys(self, obj: dict, where: str, required: tuple[str, ...], known: tuple[str, ...]) -> None:
        """Report keys of ``obj`` outside ``known`` and ``required`` keys that are missing."""
        missing = [k for k in required if k not in obj]
        if missing:
            self.add(f"{where} must have the keys {', '.join(required)}",
                     "no " + ", ".join(f'"{k}"' for k in missing))
        unknown = [k for k in obj if k not in known]
        if unknown:
            self.add(f"{where} may only have the keys {', '.join(known)}",
                     "unknown key(s) " + ", ".join(f'"{k}"' for k in unknown))

    def positive_int(self, value: object, name: str) -> int | None:
        """A positive integer (not a bool, not 640.0)."""
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            self.add(f"{name} must be a positive integer", describe(value))
            return None
        return value

    def intrinsics(self, value: object, name: str) -> np.ndarray | None:
        """A (3, 3) finite ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` with fx, fy > 0."""
        K, found = parse_array(value, (3, 3), name)
        if K is None:
            self.add(f"{name} must be a 3x3 matrix of finite numbers", found)
            return None
        ok = True
        if not (K[0, 0] > 0 and K[1, 1] > 0):
            self.add(f"{name} must have fx > 0 and fy > 0", f"fx = {K[0, 0]:g}, fy = {K[1, 1]:g}")
            ok = False
        if abs(K[0, 1]) > EXACT_TOL:
            self.add(f"{name} must have zero skew ({name}[0][1] = 0)", f"{name}[0][1] = {K[0, 1]:g}")
            ok = False
        if abs(K[1, 0]) > EXACT_TOL:
            self.add(f"{name} must have {name}[1][0] = 0", f"{name}[1][0] = {K[1, 0]:g}")
            ok = False
        if np.max(np.abs(K[2] - (0.0, 0.0, 1.0))) > EXACT_TOL:
            row = ", ".join(f"{v:g}" for v in K[2])
            self.add(f"{name} must have the last row [0, 0, 1]", f"[{row}]")
            ok = False
        return K if ok else None

    def rotation(self, value: object, name: str) -> np.ndarray | None:
        """A (3, 3) finite rotation: orthonormal within 1e-4 and det +1."""
        R, found = parse_array(value, (3, 3), name)
        if R is None:
            self.add(f"{name} must be a 3x3 matrix of finite numbers", found)
            return None
        error = float(np.max(np.abs(R @ R.T - np.eye(3))))
        det = float(np.linalg.det(R))
        if error > ROTATION_TOL or abs(det - 1.0) > ROTATION_TOL:
            rule = f"{name} must be a rotation (orthonormal, det +1)"
            if error <= ROTATION_TOL:
                self.add(rule, f"det = {det:.3f}")
            else:
                self.add(rule, f"max |R R^T - I| = {error:.2g}, det = {det:.3f}")
            return None
        return R

    def vector(self, value: object, name: str, length: int) -> np.ndarray | None:
        """A list of ``length`` finite numbers."""
        v, found = parse_array(value, (length,), name)
        if v is None:
            self.add(f"{name} must be a list of {length} finite numbers", found)
        return v

    def distortion(self, value: object, name: str) -> np.ndarray | None:
        """OpenCV distortion: 4 or 5 finite numbers."""
        length = len(value) if isinstance(value, list) and len(value) in (4, 5) else 4
        v, found = parse_array(value, (length,), name)
        if v is None:
            self.add(f"{name} must be a list of 4 or 5 finite numbers [k1, k2, p1, p2(, k3)]", found)
        return v

    def pose(self, entry: object, name: str) -> None:
        """One per-frame pose ``{"R", "t"(, "K")}``."""
        if not isinstance(entry, dict):
            self.add(f'{name} must be an object with "R", "t" and optional "K"', describe(entry))
            return
        self.keys(entry, name, ("R", "t"), POSE_KEYS)
        if "R" in entry:
            self.rotation(entry["R"], f"{name}.R")
        if "t" in entry:
            self.vector(entry["t"], f"{name}.t", 3)
        if "K" in entry:
            self.intrinsics(entry["K"], f"{name}.K")

    def frame_poses(self, value: object, name: str, frame_ids: set[int] | None, between: bool = False) -> bool | None:
        """A ``"frames"`` mapping of 6-digit frame id -> pose, ids among ``frame_ids`` (not checked when None), or,
        with ``between``, inside their span (held-out frames of the input video). Returns whether it holds
        poses, None when it is no mapping."""
        if not isinstance(value, dict):
            self.add(f'{name} must be an object mapping frame ids to {{"R", "t"}}', describe(value))
            return None
        for key, entry in value.items():
            where = f'{name}["{key}"]'
            frame_id = parse_frame_name(key)
            if frame_id is None:
                self.add(f"{name} keys must be 6-digit frame ids", f'"{key}"')
            elif frame_ids is not None and not (frame_id in frame_ids or (between and in_span(frame_id, frame_ids))):
                rule = "frame ids of the scene, or ids between its first and last frame" if between else \
                    "frame ids of the scene"
                self.add(f"{name} keys must be {rule}",
                         f'"{key}" is not among the scene\'s frames ({describe_range(frame_ids)})')
            self.pose(entry, where)
        return bool(value)


def in_span(frame_id: int, frame_ids: set[int]) -> bool:
    """Whether ``frame_id`` lies between the first and the last of ``frame_ids`` (a frame the input video had,
    held out of the scene's frames for evaluation)."""
    return bool(frame_ids) and min(frame_ids) < frame_id < max(frame_ids)


def check_cameras_json(facts: SceneFacts) -> None:
    """``cameras.json`` (optional): format, size = frame size, K, dist, per-frame poses.

    Sets ``facts.has_poses``.
    """
    path = facts.root / "cameras.json"
    if not path.exists():
        facts.has_poses = False
        return
    facts.has_poses = None
    doc = load_json(facts, path)
    if doc is None:
        return
    check = CameraChecks(facts, "cameras.json")
    if not isinstance(doc, dict):
        check.add("cameras.json must hold a JSON object", describe(doc))
        return
    check.format(doc, CAMERAS_FORMAT)
    check.keys(doc, "cameras.json", ("width", "height", "K"), CAMERAS_KEYS)
    width = check.positive_int(doc["width"], "width") if "width" in doc else None
    height = check.positive_int(doc["height"], "height") if "height" in doc else None
    size = facts.frame_size
    if width is not None and height is not None and size is not None and (width, height) != size:
        check.add(f"width and height must equal the frame size {size[0]}x{size[1]}", f"{width}x{height}")
    if "K" in doc:
        check.intrinsics(doc["K"], "K")
    if "dist" in doc:
        check.distortion(doc["dist"], "dist")
    facts.has_poses = check.frame_poses(doc["frames"], "frames", facts.frame_ids) if "frames" in doc else False

