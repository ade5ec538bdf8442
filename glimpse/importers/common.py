"""What every dataset importer shares: the options of ``glimpse import``, frame spans, masks stored as any
non-zero value, camera names, the body models a dataset's SMPL parameters need, and writing a held-out camera's
undistorted views."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image
from scipy.spatial.transform import Rotation

from glimpse.body.config import peek_body_model_kind
from glimpse.body.model_file import load_body_model_file
from glimpse.cameras.undistort import Undistorter
from glimpse.errors import GlimpseError
from glimpse.scene.writer import SceneWriter


@dataclass(frozen=True)
class ImportOptions:
    """sequence: the dataset's sequence name (None: SOURCE is the sequence folder itself); cameras: the input
    camera first, then the held-out ones (None: the dataset's protocol); frames: a span of the sequence's frames
    (None: all); eval_every: held-out images every this many imported frames; body_models: SMPL model files by
    gender (neutral, male, female) for datasets whose bodies are SMPL parameters; fps: frames per second when
    the dataset does not say."""

    sequence: str | None = None
    cameras: tuple[str, ...] | None = None
    frames: slice | None = None
    eval_every: int = 30  # pipeline.yaml import.eval_every, which glimpse import passes (a test keeps them equal)
    body_models: dict[str, Path] = field(default_factory=dict)
    fps: float | None = None


def numbered_frames(numbers: list[int], span: slice | None) -> list[int]:
    """The frame ``numbers`` (ascending: a dataset's own frame numbers) that ``span`` selects when it counts those
    numbers rather than positions (``--frames 13000:15160:4``); all of them without a span."""
    if not numbers:
        return []
    selected = range(*(span or slice(None)).indices(numbers[-1] + 1))
    return [n for n in numbers if n in selected]


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


GENDERS = ("neutral", "male", "female")
MODEL_FILE_NAMES = {"neutral": "SMPL_NEUTRAL.pkl", "male": "SMPL_MALE.pkl", "female": "SMPL_FEMALE.pkl"}


def parse_body_models(values: list[str]) -> dict[str, Path]:
    """``--body-model [GENDER=]PATH`` values (a bare path is the neutral model) -> gender -> path."""
    models = {}
    for value in values:
        gender, sep, path = value.partition("=")
        if not sep:
            gender, path = "neutral", value
        if gender not in GENDERS:
            raise GlimpseError(f"--body-model {value}: give PATH or GENDER=PATH with GENDER one of "
                               f"{', '.join(GENDERS)}")
        models[gender] = Path(path)
    return models


def smpl_model_file(options: ImportOptions, dataset: str, gender: str = "neutral", who: str = "its bodies") -> Path:
    """The SMPL-format model file of ``gender`` that the dataset's parameters belong to (``--body-model``);
    refused when missing or when it is not an SMPL model (the free body's parameters are another model's)."""
    path = options.body_models.get(gender)
    if path is None:
        option = "" if gender == "neutral" else f"{gender}="
        raise GlimpseError(f"{dataset}: {who} are parameters of SMPL's {gender} model; give it with --body-model "
                           f"{option}/path/to/{MODEL_FILE_NAMES[gender]} (SMPL's licence forbids shipping it)")
    path = Path(path).expanduser().resolve()
    if not path.is_file():
        raise GlimpseError(f"--body-model {path}: no such file")
    if peek_body_model_kind(path) != "smpl":
        raise GlimpseError(f"--body-model {path}: not an SMPL model (it is a free-body file); {dataset}'s parameters "
                           "are SMPL's")
    return path


def rest_pelvis(model_file: Path, betas: np.ndarray) -> np.ndarray:
    """The pelvis of the body shaped by ``betas`` in its rest pose (about which smplx turns global_orient):
    (3,) for betas [B], [T, 3] for betas [T, B] (the model file read once)."""
    data = load_body_model_file(model_file)
    shaped = data.v_template + np.einsum("vcb,...b->...vc", data.shapedirs[:, :, : betas.shape[-1]], betas)
    return np.einsum("v,...vc->...c", data.J_regressor[0], shaped)


def pelvis_placed_smpl(global_orient: np.ndarray, turn: Rotation, shift: np.ndarray, scale: np.ndarray,
                       source_pelvis: np.ndarray, pelvis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """smplx's (global_orient [T, 3], transl [T, 3]) for a dataset that places a body as
    ``scale · turn · SMPL(global_orient, ..., transl=0) + shift`` per frame (turn: T rotations, shift [T, 3],
    scale [T]; source_pelvis [3] or [T, 3] its rest pelvis, under the source's shape). The scene's body turns
    about its rest ``pelvis`` [3] at unit scale, so its pelvis lands exactly where the source's does; the rest
    of the body is off by (scale - 1) times its distance from the pelvis (0 where scale is 1)."""
    orient = (turn * Rotation.from_rotvec(global_orient)).as_rotvec()
    transl = scale[:, None] * turn.apply(np.array(np.broadcast_to(source_pelvis, shift.shape))) + shift - pelvis
    return orient, transl


def nonzero_mask(path: Path) -> np.ndarray | None:
    """[H, W] bool of a dataset's mask whose person pixels are any non-zero value (0/1, 0/255, part labels, a
    palette index, or any channel of a colour image); None when the file is absent."""
    if not path.is_file():
        return None
    with Image.open(path) as image:
        values = np.asarray(image)
    return values.any(axis=-1) if values.ndim == 3 else values != 0


def camera_name(text: str) -> str:
    """A dataset's camera folder name as a scene camera name (letters, digits, _ and -)."""
    cleaned = "".join(c if c.isalnum() or c in "_-" else "_" for c in text.strip()).strip("_")
    return "_".join(part for part in cleaned.split("_") if part) or "camera"


class HeldOutCamera:
    """One held-out camera of a dataset, written as it is read: registered in eval/cameras.json at its first
    image's size, every image and mask undistorted by the one Undistorter made then. K [3, 3], dist (OpenCV),
    R [3, 3] and t [3] (metres) world to camera."""

    def __init__(self, writer: SceneWriter, name: str, K: np.ndarray, dist: np.ndarray, R: np.ndarray,
                 t: np.ndarray):
        self.writer, self.name, self.K, self.dist, self.R, self.t = writer, name, K, dist, R, t
        self.undistorter: Undistorter | None = None

    def view(self, frame: int, rgb: np.ndarray, person_masks: dict[str, np.ndarray] | None = None) -> None:
        """The camera's image of ``frame`` with each person's visible mask (pid -> [H, W] bool) and their union;
        without masks the view is scored on the full frame only."""
        if self.undistorter is None:
            height, width = rgb.shape[:2]
            self.undistorter = Undistorter(self.K, self.dist, width, height)
            self.writer.eval_camera(self.name, width, height, self.K, self.R, self.t)
        masks = {pid: self.undistorter.mask(mask) for pid, mask in (person_masks or {}).items()}
        union = np.logical_or.reduce(list(masks.values())) if masks else None
        self.writer.eval_view(self.name, frame, self.undistorter.image(rgb), union, masks)
