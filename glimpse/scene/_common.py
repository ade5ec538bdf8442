"""Shared pieces of the scene validator: the violation collector, what is known
about the scene so far, folder listing, value descriptions and image checks."""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from glimpse.errors import Violation
from glimpse.io.images import (
    ImageInfo,
    ImageReadError,
    decode_image,
    frame_name,
    read_image_header,
)

#: ``<pid>`` and eval camera names: letters, digits, ``_`` or ``-``.
NAME_PATTERN = re.compile(r"[A-Za-z0-9_-]+")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
IMAGE_FORMATS = {"PNG", "JPEG", "MPO"}  # MPO: the multi-picture JPEG some phones write
RGB_MODES = {"1", "L", "LA", "P", "PA", "RGB", "RGBA"}


@dataclass
class SceneFacts:
    """What the validator has learnt about a scene; filled in file-family order.

    A field is None when the file that decides it is missing or broken, so that
    later checks that depend on it are skipped instead of repeating the error.
    frame_ids:   ids of the input frames (for a video: 0..N-1).
    frame_size:  (width, height) in pixels of the input frames.
    has_poses:   True when cameras.json has a non-empty "frames" mapping, False
                 when it has none (or no cameras.json), None when it is unreadable.
    persons:     names of the well-formed person folders in humans/.
    person_3d_files: relative paths of the smpl.npz / keypoints3d.npz files found.
    decode_images: decode every image and mask completely (a validation); False reads only their headers, for
                 a scene that has passed validation already (ids, sizes and formats are still checked).
    """

    root: Path
    violations: list[Violation] = field(default_factory=list)
    scene_yaml: dict | None = None
    camera_motion: str | None = None
    frame_ids: set[int] | None = None
    frame_paths: dict[int, Path] = field(default_factory=dict)
    video_path: Path | None = None
    frame_size: tuple[int, int] | None = None
    has_poses: bool | None = False
    persons: set[str] = field(default_factory=set)
    person_3d_files: list[str] = field(default_factory=list)
    decode_images: bool = True

    def add(self, file: str, rule: str, found: str) -> None:
        """Record one violation (``file`` relative to the scene root)."""
        self.violations.append(Violation(file, rule, found))

    def rel(self, path: Path) -> str:
        """``path`` relative to the scene root, with ``/`` separators (folders end in ``/``)."""
        text = path.relative_to(self.root).as_posix()
        return text + "/" if path.is_dir() else text


def list_folder(facts: SceneFacts, folder: Path) -> list[Path] | None:
    """The entries of ``folder`` sorted by name; None (and a violation) when it
    is not a readable folder."""
    name = folder.relative_to(facts.root).as_posix()
    if not folder.is_dir():
        facts.add(name, f"{name}/ must be a folder", "a file")
        return None
    rel = name + "/"
    try:
        return sorted(folder.iterdir(), key=lambda p: p.name)
    except OSError as err:
        facts.add(rel, f"{rel} must be a readable folder", str(err.strerror or err))
        return None


def entry_kind(path: Path) -> str:
    """``"a folder"`` or ``"a file"``, for stray-entry messages."""
    return "a folder" if path.is_dir() else "a file"


def describe(value: object) -> str:
    """A short description of a parsed YAML/JSON value for "found ..." texts."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return _number_text(value)
    if isinstance(value, str):
        return f'"{value}"' if len(value) <= 60 else f'"{value[:57]}..."'
    if isinstance(value, list):
        return f"a list of {len(value)} item(s)"
    if isinstance(value, dict):
        return f"a mapping with {len(value)} key(s)"
    return f"a {type(value).__name__}"


def _number_text(value: float) -> str:
    if isinstance(value, float) and math.isnan(value):
        return "NaN"
    if isinstance(value, float) and math.isinf(value):
        return "Infinity" if value > 0 else "-Infinity"
    return repr(value)


def quoted_list(names: Iterable[object]) -> str:
    """``a, b, c`` of the names as given."""
    return ", ".join(str(n) for n in names)


def describe_ids(ids: Iterable[int], limit: int = 5) -> str:
    """Frame ids as 6-digit names, at most ``limit`` of them then ``(+n more)``."""
    ids = sorted(ids)
    text = ", ".join(_id_text(i) for i in ids[:limit])
    return text + (f" (+{len(ids) - limit} more)" if len(ids) > limit else "")


def describe_range(ids: set[int]) -> str:
    """The scene's frames, for "not among the scene's frames (...)" texts."""
    if not ids:
        return "none"
    lo, hi = min(ids), max(ids)
    if len(ids) == hi - lo + 1:
        return f"{_id_text(lo)}..{_id_text(hi)}"
    return f"{len(ids)} frames from {_id_text(lo)} to {_id_text(hi)}"


def _id_text(frame_id: int) -> str:
    try:
        return frame_name(int(frame_id))
    except ValueError:
        return str(frame_id)


def check_image(facts: SceneFacts, path: Path, what: str) -> ImageInfo | None:
    """Decode an input image (frame, eval view, reference photo) completely (its header only when
    ``facts.decode_images`` is False).

    Records a violation when it does not decode, is not PNG/JPEG, or is not
    8-bit grey/RGB(A).  Returns its info when it decodes (even when it breaks
    the 8-bit rule, so that its size can still be compared), else None.
    """
    rel = facts.rel(path)
    try:
        info = decode_image(path)[0] if facts.decode_images else read_image_header(path)
    except ImageReadError as err:
        facts.add(rel, f"{what} must be a PNG or JPEG image that decodes completely", str(err))
        return None
    if info.format not in IMAGE_FORMATS:
        facts.add(rel, f"{what} must be a PNG or JPEG image", f"a {info.format or 'unknown'} image")
    elif info.mode not in RGB_MODES or info.bit_depth > 8:
        facts.add(rel, f"{what} must be an 8-bit grey, RGB or RGBA image", _depth_text(info))
    return info


def _depth_text(info: ImageInfo) -> str:
    article = "an" if str(info.bit_depth).startswith("8") or info.bit_depth in (11, 18) else "a"
    return f"{article} {info.bit_depth}-bit {info.format or ''} image (mode {info.mode})".replace("  ", " ")


def check_mask(facts: SceneFacts, path: Path, size: tuple[int, int] | None, size_rule: str) -> None:
    """Check one mask PNG: decodes, single-channel 8-bit (mode L, or 1-bit),
    values 0 and 255 only (not checked when ``facts.decode_images`` is False), and ``size`` = (width, height)
    when known.

    size_rule: how the size rule reads, e.g. ``"a mask must have the frame size"``.
    """
    rel = facts.rel(path)
    try:
        info, image = decode_image(path) if facts.decode_images else (read_image_header(path), None)
    except ImageReadError as err:
        facts.add(rel, "a mask must be a PNG image that decodes completely", str(err))
        return
    if info.format != "PNG":
        facts.add(rel, "a mask must be a single-channel PNG image", f"a {info.format or 'unknown'} image")
        return
    if not ((info.mode == "L" and info.bit_depth == 8) or info.mode == "1"):
        facts.add(rel, "a mask must be a single-channel 8-bit PNG (mode L, or 1-bit)", _depth_text(info))
        return
    if info.mode == "L" and image is not None:
        counts = np.bincount(np.asarray(image, dtype=np.uint8).ravel(), minlength=256)
        counts[0] = counts[255] = 0
        bad = np.flatnonzero(counts)
        if bad.size:
            values = ", ".join(str(v) for v in bad[:5]) + (f" (+{bad.size - 5} more)" if bad.size > 5 else "")
            facts.add(rel, "a mask must hold only the values 0 and 255", f"values {values}")
    if size is not None and (info.width, info.height) != size:
        facts.add(rel, f"{size_rule} {size[0]}x{size[1]}", info.size_text)


def is_finite_number(value: object) -> bool:
    """A YAML/JSON number (not a bool) that is finite."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:  # an int too large for a float
        return False
