"""The shared ``body`` section of pipeline.yaml: which body model file, the canonical
pose and the skinning of Gaussians; and the check that a scene's body parameters
belong to the model in use."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from glimpse.errors import GlimpseError


@dataclass(frozen=True)
class SkinningConfig:
    knn: int  # nearest canonical vertices blended per point
    idw_power: float  # inverse-distance exponent
    grid_resolution: int  # voxel corners per side
    grid_margin_m: float  # metres added around the body's bounding cube


@dataclass(frozen=True)
class BodyConfig:
    model_path: str  # SMPL-format file: repository-relative or absolute
    canonical_hip_angle_deg: float  # Da-pose: hips rotated +-angle about z
    skinning: SkinningConfig


def resolve_model_path(config: BodyConfig) -> Path:
    """The model file as an absolute path (relative paths are relative to the repository)."""
    from glimpse.config import REPO_ROOT

    path = Path(config.model_path).expanduser()
    path = path if path.is_absolute() else REPO_ROOT / path
    if not path.is_file():
        raise GlimpseError(
            f"body.model_path: no body model file at {path}. Give the free model "
            "(glimpse/body/assets/free_body.npz) or your own SMPL_NEUTRAL.pkl/.npz "
            '(PARAMS="body.model_path=/path/to/SMPL_NEUTRAL.pkl" or in pipeline.yaml)'
        )
    return path


def peek_body_model_kind(path: Path) -> str:
    """``free`` or ``smpl`` without loading the whole file: an .npz's ``body_model`` entry
    (absent: smpl); any .pkl is an SMPL-format pickle (``smpl``)."""
    if path.suffix == ".npz":
        with np.load(path, allow_pickle=False) as archive:
            return str(archive["body_model"]) if "body_model" in archive.files else "smpl"
    return "smpl"


def check_scene_body_model(scene_body_model: str, config: BodyConfig, scene_yaml: str) -> None:
    """Refuse a scene whose smpl.npz parameters belong to another body model than the one in use."""
    path = resolve_model_path(config)
    kind = peek_body_model_kind(path)
    if kind != scene_body_model:
        raise GlimpseError(
            f"{scene_yaml}: body_model is {scene_body_model!r}, but body.model_path ({path}) is a {kind!r} model. "
            f"Parameters of one model do not fit the other: set body.model_path to a {scene_body_model!r} model file "
            f"(free: glimpse/body/assets/free_body.npz; smpl: your SMPL_NEUTRAL.pkl) or fix scene.yaml"
        )
