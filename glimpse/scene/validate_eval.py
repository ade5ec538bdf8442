"""Rules of ``eval/`` (held-out views): eval/cameras.json, eval/<cam>/ images and masks."""

from __future__ import annotations

from pathlib import Path

from glimpse.io.images import parse_frame_name
from glimpse.scene._common import (
    IMAGE_SUFFIXES,
    NAME_PATTERN,
    SceneFacts,
    check_image,
    check_mask,
    describe,
    describe_ids,
    describe_range,
    entry_kind,
    list_folder,
)
from glimpse.scene.model import EVAL_CAMERAS_FORMAT
from glimpse.scene.validate_cameras import CameraChecks, in_span, load_json

EVAL_KEYS = ("format", "cameras")
EVAL_CAMERA_REQUIRED = ("K", "R", "t", "width", "height")
EVAL_CAMERA_KEYS = (*EVAL_CAMERA_REQUIRED, "frames")
Size = tuple[int, int] | None


def check_eval(facts: SceneFacts) -> None:
    """``eval/`` (optional): eval/cameras.json, one folder per listed camera, nothing else."""
    folder = facts.root / "eval"
    if not folder.exists():
        return
    entries = list_folder(facts, folder)
    if entries is None:
        return
    if not (folder / "cameras.json").exists():
        facts.add("eval/cameras.json", "eval/ must have eval/cameras.json", "no such file")
        return
    cameras = check_eval_cameras_json(facts, folder / "cameras.json")
    if cameras is None:
        return
    for entry in entries:
        if entry.name == "cameras.json" or entry.name in cameras:
            continue
        if entry.is_dir():
            facts.add(facts.rel(entry), "every folder in eval/ must be a camera listed in eval/cameras.json",
                      f'"{entry.name}" is not listed')
        else:
            facts.add(facts.rel(entry), "eval/ may only hold cameras.json and the camera folders", "a file")
    for name, size in cameras.items():
        cam_dir = folder / name
        if cam_dir.is_dir():
            check_eval_camera_folder(facts, cam_dir, size)
        else:
            facts.add(f"eval/{name}/", "every camera of eval/cameras.json must have a folder eval/<cam>/",
                      "a file" if cam_dir.exists() else "no such folder")


def check_eval_cameras_json(facts: SceneFacts, path: Path) -> dict[str, Size] | None:
    """``eval/cameras.json``: format, ``cameras`` mapping name -> {K, R, t, width, height(, frames)}.

    Returns camera name -> (width, height) (None when the size is invalid) for the
    well-named cameras, or None when the file gives no usable camera list.
    """
    doc = load_json(facts, path)
    if doc is None:
        return None
    check = CameraChecks(facts, "eval/cameras.json")
    if not isinstance(doc, dict):
        check.add("eval/cameras.json must hold a JSON object", describe(doc))
        return None
    check.format(doc, EVAL_CAMERAS_FORMAT)
    check.keys(doc, "eval/cameras.json", ("cameras",), EVAL_KEYS)
    if "cameras" not in doc:
        return None
    cameras = doc["cameras"]
    if not isinstance(cameras, dict) or not cameras:
        check.add('cameras must be a non-empty object mapping camera names to {"K", "R", "t", "width", "height"}',
                  describe(cameras))
        return None
    sizes: dict[str, Size] = {}
    for name, entry in cameras.items():
        well_named = NAME_PATTERN.fullmatch(name) is not None
        if not well_named:
            check.add("camera names must be letters, digits, _ or -", f'"{name}"')
        size = _check_eval_camera(check, facts, f'cameras["{name}"]', entry)
        if well_named:
            sizes[name] = size
    return sizes


def _check_eval_camera(check: CameraChecks, facts: SceneFacts, where: str, entry: object) -> Size:
    """One camera entry; returns its (width, height) when both are valid."""
    if not isinstance(entry, dict):
        check.add(f"{where} must be an object with the keys {', '.join(EVAL_CAMERA_REQUIRED)}", describe(entry))
        return None
    check.keys(entry, where, EVAL_CAMERA_REQUIRED, EVAL_CAMERA_KEYS)
    if "K" in entry:
        check.intrinsics(entry["K"], f"{where}.K")
    if "R" in entry:
        check.rotation(entry["R"], f"{where}.R")
    if "t" in entry:
        check.vector(entry["t"], f"{where}.t", 3)
    if "frames" in entry:
        check.frame_poses(entry["frames"], f"{where}.frames", facts.frame_ids, between=True)
    width = check.positive_int(entry["width"], f"{where}.width") if "width" in entry else None
    height = check.positive_int(entry["height"], f"{where}.height") if "height" in entry else None
    return (width, height) if width is not None and height is not None else None


def check_eval_camera_folder(facts: SceneFacts, cam_dir: Path, size: Size) -> None:
    """``eval/<cam>/``: ``<id>.png|jpg|jpeg`` images of scene frames at the camera's size, and masks/."""
    cam = cam_dir.name
    entries = list_folder(facts, cam_dir)
    if entries is None:
        return
    images: dict[int, Path] = {}
    masks_dir: Path | None = None
    for entry in entries:
        if entry.name == "masks" and entry.is_dir():
            masks_dir = entry
            continue
        frame_id = parse_frame_name(entry.stem) if entry.is_file() and entry.suffix in IMAGE_SUFFIXES else None
        if frame_id is None:
            facts.add(facts.rel(entry), f"eval/{cam}/ may only hold images named <6-digit frame id>.png, .jpg "
                                        f"or .jpeg and masks/", entry_kind(entry))
        elif frame_id in images:
            facts.add(facts.rel(entry), f"each frame id must appear once in eval/{cam}/",
                      f"{images[frame_id].name} and {entry.name}")
        else:
            images[frame_id] = entry
    if not images:
        facts.add(f"eval/{cam}/", "an eval camera must have at least one image", "no images")
    for frame_id, path in images.items():
        if facts.frame_ids is not None and not (frame_id in facts.frame_ids or in_span(frame_id, facts.frame_ids)):
            facts.add(facts.rel(path), "an eval image's frame id must be a frame of the scene, or lie between its "
                                       "first and last frame (a held-out frame of the input video)",
                      f"{path.stem}, not among the scene's frames ({describe_range(facts.frame_ids)})")
        info = check_image(facts, path, "an eval image")
        if info is not None and size is not None and (info.width, info.height) != size:
            facts.add(facts.rel(path), f"an eval image must have its camera's size {size[0]}x{size[1]} "
                                       f"(eval/cameras.json)", info.size_text)
    if masks_dir is None:  # masks are optional: without them the camera is scored on the full frame only
        return
    check_eval_masks(facts, masks_dir, images, size)


def check_eval_masks(facts: SceneFacts, masks_dir: Path, images: dict[int, Path], size: Size) -> None:
    """``eval/<cam>/masks/``: a union mask ``<id>.png`` for exactly the image ids, and ``<pid>/`` folders."""
    cam = masks_dir.parent.name
    union: set[int] = set()
    for entry in list_folder(facts, masks_dir) or []:
        if entry.is_dir():
            check_eval_person_masks(facts, entry, images, size)
            continue
        frame_id = parse_frame_name(entry.stem) if entry.suffix == ".png" else None
        if frame_id is None:
            facts.add(facts.rel(entry), "masks/ may only hold union masks <6-digit frame id>.png and "
                                        "<pid>/ folders", "a file")
            continue
        union.add(frame_id)
        if frame_id not in images:
            facts.add(facts.rel(entry), f"a union mask must have an image with the same frame id in eval/{cam}/",
                      f"no image {entry.stem}")
        check_mask(facts, entry, size, "an eval mask must have its camera's size")
    missing = sorted(set(images) - union)
    if missing:
        facts.add(f"eval/{cam}/masks/", _union_rule(cam), f"no mask for {describe_ids(missing)}")


def _union_rule(cam: str) -> str:
    return f"every image of eval/{cam}/ must have a union mask eval/{cam}/masks/<id>.png with the same frame id"


def check_eval_person_masks(facts: SceneFacts, folder: Path, images: dict[int, Path], size: Size) -> None:
    """``eval/<cam>/masks/<pid>/``: pid a person of humans/, ``<id>.png`` masks of the camera's image ids."""
    cam = folder.parent.parent.name
    if folder.name not in facts.persons:
        persons = ", ".join(sorted(facts.persons)) or "none"
        facts.add(facts.rel(folder), "a per-person mask folder eval/<cam>/masks/<pid>/ must name a person "
                                     "of humans/", f'"{folder.name}" (the persons are: {persons})')
    for entry in list_folder(facts, folder) or []:
        frame_id = parse_frame_name(entry.stem) if entry.is_file() and entry.suffix == ".png" else None
        if frame_id is None:
            facts.add(facts.rel(entry), "masks/<pid>/ may only hold masks named <6-digit frame id>.png",
                      entry_kind(entry))
            continue
        if frame_id not in images:
            facts.add(facts.rel(entry), f"a person mask's frame id must be one of the image ids of eval/{cam}/",
                      f"no image {entry.stem}")
        check_mask(facts, entry, size, "an eval mask must have its camera's size")
