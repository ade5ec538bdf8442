"""Rules of ``humans/<pid>/``: folder names, smpl.npz, keypoints2d/3d.npz, masks/, reference/."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from glimpse.io.images import parse_frame_name
from glimpse.scene._common import (
    IMAGE_SUFFIXES,
    NAME_PATTERN,
    SceneFacts,
    check_image,
    check_mask,
    describe_ids,
    describe_range,
    entry_kind,
    list_folder,
)
from glimpse.scene.model import KEYPOINT_LAYOUTS, RELATIVE3D_KEY

RESERVED_PID = "union"
PERSON_FILES = ("smpl.npz", "keypoints2d.npz", "keypoints3d.npz")
PERSON_FOLDERS = ("masks", "reference")
PERSON_3D_FILES = ("smpl.npz", "keypoints3d.npz")
#: smpl.npz arrays other than frame_ids: key -> shape ("T" = number of frame ids)
SMPL_ARRAYS: dict[str, tuple[int | str, ...]] = {
    "betas": (10,), "global_orient": ("T", 3), "body_pose": ("T", 69), "transl": ("T", 3)}
Shape = tuple[int | str, ...]
_ZIP_MAGIC = b"PK\x03\x04"
_NPY_MAGIC = b"\x93NUMPY"


def check_humans(facts: SceneFacts) -> None:
    """``humans/`` (optional): person folders only, each checked; fills ``facts.persons``."""
    humans = facts.root / "humans"
    if not humans.exists():
        return
    entries = list_folder(facts, humans)
    for entry in entries or []:
        if not entry.is_dir():
            facts.add(facts.rel(entry), "humans/ may only hold person folders humans/<pid>/", "a file")
            continue
        if NAME_PATTERN.fullmatch(entry.name) and entry.name != RESERVED_PID:
            facts.persons.add(entry.name)
        else:
            facts.add(facts.rel(entry), f'a person folder must be named with letters, digits, _ or - '
                                        f'(and not "{RESERVED_PID}")', f'"{entry.name}"')
        check_person(facts, entry)


def check_person(facts: SceneFacts, folder: Path) -> None:
    """One ``humans/<pid>/``: only the known files, at least one kind of data, each file valid."""
    entries = list_folder(facts, folder)
    if entries is None:
        return
    has_data = False
    for entry in entries:
        name, rel = entry.name, facts.rel(entry)
        if name in PERSON_FILES and entry.is_file():
            has_data = True
            if name in PERSON_3D_FILES:
                facts.person_3d_files.append(rel)
            if name == "smpl.npz":
                check_smpl(facts, entry)
            else:
                check_keypoints(facts, entry, *(("keypoints", 3) if name == "keypoints2d.npz" else ("joints", 4)))
        elif name == "masks" and entry.is_dir():
            has_data = check_person_masks(facts, entry) or has_data
        elif name == "reference" and entry.is_dir():
            check_references(facts, entry)
        else:
            expected = " (it must be a folder)" if name in PERSON_FOLDERS else (
                " (it must be a file)" if name in PERSON_FILES else "")
            facts.add(rel, "a person folder may only hold smpl.npz, keypoints2d.npz, keypoints3d.npz, "
                           "masks/ and reference/", entry_kind(entry) + expected)
    if not has_data:
        facts.add(facts.rel(folder), "a person must have data: smpl.npz, keypoints2d.npz, keypoints3d.npz "
                                     "or at least one mask in masks/", "none of them")


# --- npz files ----------------------------------------------------------------------------------

def load_npz(facts: SceneFacts, path: Path) -> dict[str, np.ndarray] | None:
    """All arrays of an .npz archive, loaded without pickle; None (with a violation) when it fails."""
    rel, rule = facts.rel(path), "an .npz file must load with numpy.load(allow_pickle=False)"
    with open(path, "rb") as handle:
        magic = handle.read(6)
    if magic == _NPY_MAGIC:
        facts.add(rel, rule, "a single .npy array, not an .npz archive")
        return None
    if not magic.startswith(_ZIP_MAGIC):
        facts.add(rel, rule, "not an .npz archive (the file is not a zip archive)")
        return None
    try:
        data = np.load(path, allow_pickle=False)
    except Exception as err:  # zipfile, pickle and format errors all mean a broken file
        facts.add(rel, rule, f"{type(err).__name__}: {err}")
        return None
    if not isinstance(data, np.lib.npyio.NpzFile):
        facts.add(rel, rule, "a single .npy array, not an .npz archive")
        return None
    try:
        return {key: data[key] for key in data.files}
    except Exception as err:
        facts.add(rel, rule, f"{type(err).__name__}: {err}")
        return None
    finally:
        data.close()


def _require_keys(facts: SceneFacts, rel: str, arrays: dict, keys: tuple[str, ...]) -> None:
    missing = [k for k in keys if k not in arrays]
    if missing:
        facts.add(rel, f"{Path(rel).name} must have the arrays {', '.join(keys)}",
                  "no " + ", ".join(f'"{k}"' for k in missing))


def _check_frame_ids(facts: SceneFacts, rel: str, arrays: dict) -> int | None:
    """``frame_ids``: (T,) integers, T >= 1, unique, among the scene's frames. Returns T (None if unusable)."""
    ids = arrays.get("frame_ids")
    if ids is None:
        return None
    if ids.ndim != 1 or not np.issubdtype(ids.dtype, np.integer) or len(ids) < 1:
        facts.add(rel, "frame_ids must be a 1-D integer array of at least one id",
                  f"shape {ids.shape}, dtype {ids.dtype}")
        return None
    values, counts = np.unique(ids, return_counts=True)
    if np.any(counts > 1):
        facts.add(rel, "frame_ids must be unique", f"{describe_ids(values[counts > 1])} more than once")
    if facts.frame_ids is not None:
        unknown = [int(v) for v in values if int(v) not in facts.frame_ids]
        if unknown:
            facts.add(rel, "frame_ids must be frame ids of the scene",
                      f"{describe_ids(unknown)}, not among the scene's frames ({describe_range(facts.frame_ids)})")
    return len(ids)


def _check_layout(facts: SceneFacts, rel: str, arrays: dict) -> int | None:
    """``layout``: scalar string naming a known layout. Returns its joint count J (None if unusable)."""
    layout = arrays.get("layout")
    if layout is None:
        return None
    known = ", ".join(f"{name} ({joints} joints)" for name, joints in KEYPOINT_LAYOUTS.items())
    if layout.shape != () or layout.dtype.kind != "U":
        facts.add(rel, f"layout must be a scalar string, one of {known}", f"shape {layout.shape}, dtype {layout.dtype}")
        return None
    name = str(layout.item())
    if name not in KEYPOINT_LAYOUTS:
        facts.add(rel, f"layout must be one of {known}", f'"{name}"')
        return None
    return KEYPOINT_LAYOUTS[name]


def _shape_matches(shape: tuple[int, ...], pattern: Shape, sizes: dict[str, int | None]) -> bool:
    if len(shape) != len(pattern):
        return False
    for dim, want in zip(shape, pattern):
        want = sizes.get(want) if isinstance(want, str) else want
        if want is not None and dim != want:
            return False
    return True


def _shape_text(pattern: Shape, sizes: dict[str, int | None]) -> str:
    dims = ", ".join(str(d) for d in pattern) + ("," if len(pattern) == 1 else "")
    known = [f"{k} = {v}" for k, v in sizes.items() if v is not None and k in pattern]
    return f"({dims})" + (f" with {', '.join(known)}" if known else "")


def _check_array(facts: SceneFacts, rel: str, key: str, array: np.ndarray, pattern: Shape,
                 sizes: dict[str, int | None]) -> np.ndarray | None:
    """A real-valued array of ``pattern`` shape with only finite values; returns it as float64 or None."""
    numeric = np.issubdtype(array.dtype, np.integer) or np.issubdtype(array.dtype, np.floating)
    if not numeric or not _shape_matches(array.shape, pattern, sizes):
        facts.add(rel, f"{key} must be a numeric array of shape {_shape_text(pattern, sizes)}",
                  f"shape {array.shape}, dtype {array.dtype}")
        return None
    values = array.astype(np.float64)
    bad = ~np.isfinite(values)
    if bad.any():
        first = tuple(int(i) for i in np.argwhere(bad)[0])
        facts.add(rel, f"{key} must hold only finite numbers",
                  f"{int(bad.sum())} NaN or infinite value(s), the first at index {first}")
        return None
    return values


def check_smpl(facts: SceneFacts, path: Path) -> None:
    """``smpl.npz``: frame_ids (T,), betas (10,), global_orient (T, 3), body_pose (T, 69), transl (T, 3)."""
    arrays = load_npz(facts, path)
    if arrays is None:
        return
    rel = facts.rel(path)
    _require_keys(facts, rel, arrays, ("frame_ids", *SMPL_ARRAYS))
    sizes = {"T": _check_frame_ids(facts, rel, arrays)}
    for key, pattern in SMPL_ARRAYS.items():
        if key in arrays:
            _check_array(facts, rel, key, arrays[key], pattern, sizes)


def check_keypoints(facts: SceneFacts, path: Path, key: str, channels: int) -> None:
    """keypoints2d.npz (``key="keypoints"``, 3 channels: x, y, confidence; optionally ``relative3d``, 4 channels:
    metric x, y, z from the mid hip, confidence) or keypoints3d.npz (``key="joints"``, 4 channels: x, y, z,
    confidence): frame_ids, layout, (T, J, channels)."""
    arrays = load_npz(facts, path)
    if arrays is None:
        return
    rel = facts.rel(path)
    _require_keys(facts, rel, arrays, ("frame_ids", "layout", key))
    sizes = {"T": _check_frame_ids(facts, rel, arrays), "J": _check_layout(facts, rel, arrays)}
    present = [(key, channels)] + ([(RELATIVE3D_KEY, 4)] if key == "keypoints" and RELATIVE3D_KEY in arrays else [])
    for name, width in present:
        values = _check_array(facts, rel, name, arrays[name], ("T", "J", width), sizes) if name in arrays else None
        if values is not None and values.size:
            confidence = values[..., -1]
            low, high = float(confidence.min()), float(confidence.max())
            if low < 0.0 or high > 1.0:
                facts.add(rel, f"{name} confidence (the last channel) must be in [0, 1]",
                          f"values from {low:g} to {high:g}")


# --- masks/ and reference/ --------------------------------------------------------------------------

def check_person_masks(facts: SceneFacts, folder: Path) -> bool:
    """``humans/<pid>/masks/``: only ``<id>.png`` of scene frames, valid masks of the frame size.
    Returns whether it holds at least one mask file."""
    entries = list_folder(facts, folder)
    count = 0
    for entry in entries or []:
        frame_id = parse_frame_name(entry.stem) if entry.suffix == ".png" and entry.is_file() else None
        if frame_id is None:
            facts.add(facts.rel(entry), "masks/ may only hold masks named <6-digit frame id>.png", entry_kind(entry))
            continue
        count += 1
        if facts.frame_ids is not None and frame_id not in facts.frame_ids:
            facts.add(facts.rel(entry), "a mask's frame id must be a frame of the scene",
                      f"{entry.stem}, not among the scene's frames ({describe_range(facts.frame_ids)})")
        check_mask(facts, entry, facts.frame_size, "a mask must have the frame size")
    return count > 0


def check_references(facts: SceneFacts, folder: Path) -> None:
    """``humans/<pid>/reference/``: only .png/.jpg/.jpeg images (any name, any size) that decode."""
    for entry in list_folder(facts, folder) or []:
        if entry.is_file() and entry.suffix.lower() in IMAGE_SUFFIXES:
            check_image(facts, entry, "a reference image")
        else:
            facts.add(facts.rel(entry), "reference/ may only hold .png, .jpg or .jpeg images", entry_kind(entry))
