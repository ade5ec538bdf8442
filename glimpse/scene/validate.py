"""The ``glimpse-scene/1`` validator: ``scene.yaml``, ``frames/`` or ``video.mp4``,
and the orchestration of the other file families (cameras, humans, eval).

:func:`validate_scene` never raises for bad content: it returns every
violation it finds, each naming the file (relative to the scene root), the rule
as it should hold, and what was found.  Checks that depend on a broken file
(e.g. "a mask's frame id must be a frame of the scene" when frames/ is
missing) are skipped rather than repeated.
"""

from __future__ import annotations

import os
import re
from collections import Counter, defaultdict
from collections.abc import Callable
from pathlib import Path

import cv2
import yaml

from glimpse.config import safe_load_yaml
from glimpse.errors import Violation
from glimpse.io.images import FRAME_ID_MAX, ImageInfo, parse_frame_name
from glimpse.scene._common import (
    IMAGE_SUFFIXES,
    SceneFacts,
    check_image,
    describe,
    is_finite_number,
    list_folder,
)
from glimpse.scene.model import SCENE_FORMAT_VERSION
from glimpse.scene.validate_cameras import check_cameras_json
from glimpse.scene.validate_eval import check_eval
from glimpse.scene.validate_humans import check_humans

__all__ = ["validate_scene", "inspect_scene", "SCENE_KEYS", "CAMERA_MOTIONS", "BODY_MODELS"]

SCENE_KEYS = ("format", "name", "fps", "camera_motion", "body_model", "overrides")
KNOWN_SCENE_FORMATS = (SCENE_FORMAT_VERSION,)
CAMERA_MOTIONS = ("static", "moving", "unknown")
BODY_MODELS = ("free", "smpl")
_SCENE_NAME = re.compile(r"[A-Za-z0-9_.-]+")


def validate_scene(root: str | Path) -> list[Violation]:
    """Check a scene folder against ``glimpse-scene/1``; returns all violations (empty = valid)."""
    return inspect_scene(root).violations


def inspect_scene(root: str | Path, decode_images: bool = True) -> SceneFacts:
    """Validate a scene and return what was learnt on the way (frame ids, frame
    size...) with the violations, so that the reader need not decode again.
    ``decode_images`` False reads images by their headers only (SceneFacts)."""
    facts = SceneFacts(root=Path(root), decode_images=decode_images)
    if not facts.root.is_dir():
        facts.add(".", "the scene must be a folder", "a file" if facts.root.exists() else "no such folder")
        return facts
    steps: list[tuple[str, Callable[[SceneFacts], None]]] = [
        (".", check_links_stay_inside),
        ("scene.yaml", check_scene_yaml),
        ("frames/", check_frame_source),
        ("cameras.json", check_cameras_json),
        ("humans/", check_humans),
        ("humans/", check_moving_camera_3d),
        ("eval/", check_eval),
    ]
    for file, step in steps:
        try:
            step(facts)
        except OSError as err:  # unreadable files or folders: a violation, not a traceback
            facts.add(err.filename and _relative(facts, err.filename) or file,
                      "scene files must be readable", str(err.strerror or err))
    return facts


def _relative(facts: SceneFacts, filename: str) -> str:
    try:
        return Path(filename).relative_to(facts.root).as_posix()
    except ValueError:
        return str(filename)


def check_links_stay_inside(facts: SceneFacts) -> None:
    """No symbolic link under the scene may lead out of it: the pipeline reads only the scene's own files
    (a scene handed over must not make Glimpse read, and copy into a run, what lies elsewhere)."""
    root = facts.root.resolve()
    rule = "every file of a scene lies inside its folder: a symbolic link may not point outside it (copy the files in)"
    for dirpath, dirnames, filenames in os.walk(facts.root):
        for name in sorted(dirnames + filenames):
            path = Path(dirpath) / name
            if path.is_symlink() and not path.resolve().is_relative_to(root):
                facts.add(path.relative_to(facts.root).as_posix(), rule, f"links to {os.readlink(path)}")


# --- scene.yaml ---------------------------------------------------------------------------

_FAILED = object()


def _load_yaml(facts: SceneFacts, path: Path) -> object:
    """Parse scene.yaml; returns the document, or ``_FAILED`` (with a violation)."""
    if not path.exists():
        facts.add("scene.yaml", "scene.yaml must exist", "no such file")
        return _FAILED
    if path.is_dir():
        facts.add("scene.yaml", "scene.yaml must be a YAML file", "a folder")
        return _FAILED
    try:
        return safe_load_yaml(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as err:
        facts.add("scene.yaml", "scene.yaml must be UTF-8 text", str(err))
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" at line {mark.line + 1} column {mark.column + 1}" if mark is not None else ""
        facts.add("scene.yaml", "scene.yaml must be valid YAML", f"{getattr(err, 'problem', None) or err}{where}")
    return _FAILED


def check_scene_yaml(facts: SceneFacts) -> None:
    """``scene.yaml``: format, name, fps, camera_motion, body_model, overrides, no other keys.

    Sets ``facts.scene_yaml`` and ``facts.camera_motion`` (None when invalid).
    """
    doc = _load_yaml(facts, facts.root / "scene.yaml")
    if doc is _FAILED:
        return
    if not isinstance(doc, dict):
        facts.add("scene.yaml", "scene.yaml must hold a mapping of keys",
                  "an empty file" if doc is None else describe(doc))
        return
    facts.scene_yaml = doc

    def add(rule: str, found: str) -> None:
        facts.add("scene.yaml", rule, found)

    fmt = doc.get("format")
    if "format" not in doc:
        add(f'format must be "{SCENE_FORMAT_VERSION}"', 'no "format" key')
    elif fmt != SCENE_FORMAT_VERSION:
        add(f'format must be "{SCENE_FORMAT_VERSION}"',
            f"{describe(fmt)} (known versions: {', '.join(KNOWN_SCENE_FORMATS)})")

    name = doc.get("name")
    name_rule = "name must be a non-empty string of letters, digits, _, - or . (it names the output folder)"
    if "name" not in doc:
        add(name_rule, 'no "name" key')
    elif not isinstance(name, str) or not _SCENE_NAME.fullmatch(name) or set(name) == {"."}:
        add(name_rule, describe(name))

    fps = doc.get("fps")
    if "fps" not in doc:
        add("fps must be a positive finite number", 'no "fps" key')
    elif not is_finite_number(fps) or fps <= 0:
        add("fps must be a positive finite number", describe(fps))

    facts.camera_motion = _choice(facts, doc, "camera_motion", CAMERA_MOTIONS, "unknown")
    _choice(facts, doc, "body_model", BODY_MODELS, "free")
    _check_overrides(facts, doc)

    unknown = [k for k in doc if k not in SCENE_KEYS]
    if unknown:
        add(f"scene.yaml may only have the keys {', '.join(SCENE_KEYS)}",
            "unknown key(s) " + ", ".join(f'"{k}"' for k in unknown))


def _choice(facts: SceneFacts, doc: dict, key: str, choices: tuple[str, ...], default: str) -> str | None:
    """An optional key with a fixed set of values; returns it, the default, or None when invalid."""
    if key not in doc:
        return default
    value = doc[key]
    if not isinstance(value, str) or value not in choices:
        facts.add("scene.yaml", f"{key} must be one of {' | '.join(choices)} (default {default})", describe(value))
        return None
    return value


def _check_overrides(facts: SceneFacts, doc: dict) -> None:
    """``overrides``: optional mapping of stage/section name -> mapping (an empty block is allowed)."""
    overrides = doc.get("overrides")
    if overrides is None:
        return
    if not isinstance(overrides, dict):
        facts.add("scene.yaml", "overrides must be a mapping of stage name -> mapping of parameters",
                  describe(overrides))
        return
    for key, value in overrides.items():
        if not isinstance(key, str) or not isinstance(value, dict):
            facts.add("scene.yaml", "overrides must be a mapping of stage name -> mapping of parameters",
                      f"overrides[{describe(key)}] = {describe(value)}")


# --- frames/ or video.mp4 ------------------------------------------------------------------

def check_frame_source(facts: SceneFacts) -> None:
    """Exactly one of ``frames/`` and ``video.mp4``; sets frame ids, paths and size."""
    frames_dir, video = facts.root / "frames", facts.root / "video.mp4"
    rule = "a scene must have exactly one of frames/ and video.mp4"
    if frames_dir.exists() and video.exists():
        facts.add("frames/", rule, "both frames/ and video.mp4")
        check_frames_folder(facts, frames_dir)
    elif frames_dir.exists():
        check_frames_folder(facts, frames_dir)
    elif video.exists():
        check_video(facts, video)
    else:
        facts.add("frames/", rule, "neither frames/ nor video.mp4")


def check_frames_folder(facts: SceneFacts, frames_dir: Path) -> None:
    """``frames/``: only ``<id>.png|jpg|jpeg`` files, >= 1, ids unique, 8-bit, all one size."""
    entries = list_folder(facts, frames_dir)
    if entries is None:
        return
    by_id: dict[int, list[Path]] = defaultdict(list)
    for entry in entries:
        frame_id = parse_frame_name(entry.stem) if entry.suffix in IMAGE_SUFFIXES and entry.is_file() else None
        if frame_id is None:
            facts.add(facts.rel(entry), "frames/ may only hold frame images named <6-digit id>.png, .jpg or .jpeg",
                      "a folder" if entry.is_dir() else "a file with another name")
        else:
            by_id[frame_id].append(entry)
    if not by_id:
        facts.add("frames/", "frames/ must hold at least one frame", "no frame images")
        return
    for frame_id, paths in by_id.items():
        for extra in paths[1:]:
            facts.add(facts.rel(extra), "each frame id must appear once in frames/",
                      " and ".join(p.name for p in paths))
    facts.frame_ids = set(by_id)
    facts.frame_paths = {frame_id: by_id[frame_id][0] for frame_id in sorted(by_id)}
    infos = {frame_id: check_image(facts, path, "a frame") for frame_id, path in facts.frame_paths.items()}
    facts.frame_size = _check_same_size(facts, {i: info for i, info in infos.items() if info is not None})


def _check_same_size(facts: SceneFacts, infos: dict[int, ImageInfo]) -> tuple[int, int] | None:
    """Flag frames whose size differs from the most common one (ties: the first frame's); returns it."""
    if not infos:
        return None
    sizes = Counter((info.width, info.height) for info in infos.values())
    size = sizes.most_common(1)[0][0]
    for frame_id, info in infos.items():
        if (info.width, info.height) != size:
            facts.add(facts.rel(facts.frame_paths[frame_id]), "every frame must have the same size",
                      f"{info.size_text}, the others are {size[0]}x{size[1]}")
    return size


def check_video(facts: SceneFacts, video: Path) -> None:
    """``video.mp4``: opens with OpenCV and has >= 1 frame; frame ids are 0..N-1 (counted by decoding)."""
    if video.is_dir():
        facts.add("video.mp4", "video.mp4 must be a video file", "a folder")
        return
    capture = cv2.VideoCapture(str(video))
    try:
        if not capture.isOpened():
            facts.add("video.mp4", "video.mp4 must be a video that OpenCV can open", "it does not open")
            return
        ok, first = capture.read()
        if not ok or first is None:
            facts.add("video.mp4", "video.mp4 must have at least one frame", "no decodable frame")
            return
        count = 1
        while capture.grab():
            count += 1
    finally:
        capture.release()
    if count > FRAME_ID_MAX + 1:
        facts.add("video.mp4", f"video.mp4 may have at most {FRAME_ID_MAX + 1} frames (6-digit frame ids)",
                  f"{count} frames")
        return
    facts.video_path = video
    facts.frame_ids = set(range(count))
    facts.frame_size = (int(first.shape[1]), int(first.shape[0]))


# --- cross-file rule --------------------------------------------------------------------------

def check_moving_camera_3d(facts: SceneFacts) -> None:
    """A moving camera with no per-frame poses can only carry 2D person data."""
    if facts.camera_motion != "moving" or facts.has_poses is not False:
        return
    cameras = "cameras.json without per-frame poses" if (facts.root / "cameras.json").exists() else "no cameras.json"
    for file in facts.person_3d_files:
        facts.add(file, "a moving camera with no per-frame poses in cameras.json can only carry 2D person data "
                        "(keypoints2d.npz, masks/)", f"camera_motion: moving and {cameras}")
