"""What every dataset importer shares: the options of ``glimpse import``, frame spans, held-out views
undistorted to pinhole images, and the body model a dataset's SMPL parameters need."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from glimpse.body.config import peek_body_model_kind
from glimpse.cameras.undistort import Undistorter
from glimpse.errors import GlimpseError


@dataclass(frozen=True)
class ImportOptions:
    """sequence: the dataset's sequence name (None: SOURCE is the sequence folder itself); cameras: the input
    camera first, then the held-out ones (None: the dataset's protocol); frames: a span of the sequence's frames
    (None: all); eval_every: held-out images every this many imported frames; body_model: a body model file
    for datasets whose bodies are SMPL parameters; fps: frames per second when the dataset does not say."""

    sequence: str | None = None
    cameras: tuple[str, ...] | None = None
    frames: slice | None = None
    eval_every: int = 30
    body_model: Path | None = None
    fps: float | None = None


def parse_span(text: str) -> slice:
    """``A:B`` or ``A:B:STEP`` (B exclusive, either end may be empty) or ``A`` -> a slice over the sequence's
    frames, in the sequence's own order (0 = its first frame)."""
    parts = text.split(":")
    try:
        values = [int(p) if p.strip() else None for p in parts]
    except ValueError:
        values = []
    if not 1 <= len(values) <= 3 or (len(values) == 1 and values[0] is None) or (len(values) == 3 and values[2] == 0):
        raise GlimpseError(f"--frames {text!r}: give A, A:B or A:B:STEP (frame positions, B excluded)")
    if len(values) == 1:
        return slice(values[0], values[0] + 1)
    return slice(*values)


def smpl_model_file(options: ImportOptions, dataset: str) -> Path:
    """The SMPL-format model file the dataset's parameters belong to (``--body-model``); refused when missing or
    when it is not an SMPL model (the free body's parameters are another model's)."""
    path = options.body_model
    if path is None:
        raise GlimpseError(f"{dataset}: its bodies are SMPL parameters; give the SMPL model they belong to with "
                           "--body-model /path/to/SMPL_NEUTRAL.pkl (SMPL's licence forbids shipping it)")
    path = Path(path).expanduser().resolve()
    if not path.is_file():
        raise GlimpseError(f"--body-model {path}: no such file")
    if peek_body_model_kind(path) != "smpl":
        raise GlimpseError(f"--body-model {path}: not an SMPL model (it is a free-body file); {dataset}'s parameters "
                           "are SMPL's")
    return path


def undistorted_view(K: np.ndarray, dist: np.ndarray | None, rgb: np.ndarray, mask: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """A held-out view as the scene format wants it, pinhole with the same K: (rgb [H, W, 3] uint8, mask [H, W]
    bool) undistorted."""
    undistorter = Undistorter(K, dist, rgb.shape[1], rgb.shape[0])
    return undistorter.image(rgb), undistorter.mask(mask)


def camera_name(text: str) -> str:
    """A dataset's camera folder name as a scene camera name (letters, digits, _ and -)."""
    cleaned = "".join(c if c.isalnum() or c in "_-" else "_" for c in text.strip()).strip("_")
    return "_".join(part for part in cleaned.split("_") if part) or "camera"
