"""The shared ``body`` section of pipeline.yaml: which body model file, the canonical
pose and the skinning of Gaussians; and the check that a scene's body parameters
belong to the model in use."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from glimpse.errors import ConfigError, GlimpseError


@dataclass(frozen=True)
class SkinningConfig:
    knn: int  # nearest canonical vertices blended per point
    idw_power: float  # inverse-distance exponent
    grid_resolution: int  # voxel corners per side
    grid_margin_m: float  # metres added around the body's bounding cube


@dataclass(frozen=True)
class BodyConfig:
    model_path: str  # SMPL-format file: repository-relative or absolute
    person_model_paths: list[str]  # "PID=PATH": that person's own model file (gendered SMPL)
    canonical_hip_angle_deg: float  # Da-pose: hips rotated +-angle about z
    skinning: SkinningConfig

    def __post_init__(self) -> None:
        person_model_files(self)  # malformed entries are refused when the section is read


def _existing(path_text: str, parameter: str) -> Path:
    """A model file as an absolute path (relative paths are relative to the repository); missing: an error."""
    path = repository_path(path_text)
    if not path.is_file():
        raise GlimpseError(
            f"{parameter}: no body model file at {path}. Give the free model "
            "(glimpse/body/assets/free_body.npz) or your own SMPL_NEUTRAL.pkl/.npz "
            '(PARAMS="body.model_path=/path/to/SMPL_NEUTRAL.pkl" or in pipeline.yaml)'
        )
    return path


def resolve_model_path(config: BodyConfig) -> Path:
    """The shared model file as an absolute path (relative paths are relative to the repository)."""
    return _existing(config.model_path, "body.model_path")


def pid_path_entries(entries: list[str], parameter: str, example: str) -> dict[str, str]:
    """PID=PATH ``entries`` of the list parameter ``parameter`` as pid -> path text (not checked on disk); an
    entry without both parts, or a pid given twice, is an error (``example`` shows one right entry)."""
    paths: dict[str, str] = {}
    for entry in entries:
        pid, sep, path = str(entry).partition("=")
        if not sep or not pid.strip() or not path.strip():
            raise ConfigError(f"{parameter}: {entry!r} is not PID=PATH (e.g. {example})")
        if pid.strip() in paths:
            raise ConfigError(f"{parameter}: person {pid.strip()!r} is given twice")
        paths[pid.strip()] = path.strip()
    return paths


def repository_path(path_text: str) -> Path:
    """A path parameter as an absolute path: absolute as given (``~`` expanded), else relative to the repository."""
    from glimpse.config import REPO_ROOT

    path = Path(path_text).expanduser()
    return path if path.is_absolute() else REPO_ROOT / path


def person_model_files(config: BodyConfig) -> dict[str, str]:
    """``body.person_model_paths`` as pid -> path text (not checked on disk); malformed entries are errors."""
    return pid_path_entries(config.person_model_paths, "body.person_model_paths", "p0=/smpl/SMPL_MALE.pkl")


def resolve_person_model_paths(config: BodyConfig) -> dict[str, Path]:
    """pid -> absolute model file for each person ``body.person_model_paths`` names (each must exist)."""
    return {pid: _existing(path, f"body.person_model_paths ({pid})")
            for pid, path in person_model_files(config).items()}


def peek_body_model_kind(path: Path) -> str:
    """``free`` or ``smpl`` without loading the whole file: an .npz's ``body_model`` entry
    (absent: smpl); any .pkl is an SMPL-format pickle (``smpl``)."""
    if path.suffix == ".npz":
        with np.load(path, allow_pickle=False) as archive:
            return str(archive["body_model"]) if "body_model" in archive.files else "smpl"
    return "smpl"


def check_scene_body_model(scene_body_model: str, config: BodyConfig, scene_yaml: str) -> None:
    """Refuse a scene whose smpl.npz parameters belong to another body model than the ones in use (the shared
    file and every person's own)."""
    files = {"body.model_path": resolve_model_path(config)}
    files.update({f"body.person_model_paths ({pid})": path for pid, path in resolve_person_model_paths(config).items()})
    for parameter, path in files.items():
        kind = peek_body_model_kind(path)
        if kind != scene_body_model:
            raise GlimpseError(
                f"{scene_yaml}: body_model is {scene_body_model!r}, but {parameter} ({path}) is a {kind!r} model. "
                f"Parameters of one model do not fit the other: set it to a {scene_body_model!r} model file "
                f"(free: glimpse/body/assets/free_body.npz; smpl: your SMPL_NEUTRAL.pkl) or fix scene.yaml"
            )
