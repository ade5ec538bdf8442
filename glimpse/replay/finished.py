"""A finished run read back: stage 01's cameras, stage 06's background and people, and the body
model and renderer settings they were trained with (from the run's resolved parameters)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from glimpse.body.config import BodyConfig
from glimpse.body.models import BodyModels
from glimpse.cameras.model import PinholeCamera
from glimpse.config import config_from_mapping
from glimpse.errors import GlimpseError
from glimpse.gaussians.model import GaussianModel
from glimpse.gaussians.ply import read_gaussians_ply
from glimpse.humans.load import load_trained_people
from glimpse.humans.person import PersonGaussians
from glimpse.io.cameras_json import read_cameras_json
from glimpse.render.config import RenderConfig


@dataclass
class FinishedRun:
    """What stages 01 and 06 left in a run folder: cameras, background and people."""

    folder: Path
    width: int
    height: int
    cameras: dict[int, PinholeCamera]
    background: GaussianModel
    people: list[PersonGaussians]
    body_models: BodyModels  # each person's body model
    render: RenderConfig


def load_finished_run(folder: Path) -> FinishedRun:
    """Read ``folder`` (OUT/<scene>); one clear error when stage 06 has not finished there."""
    joint, sfm = folder / "06_joint_opt", folder / "01_sfm"
    if not (joint / "manifest.json").is_file():
        raise GlimpseError(f"{folder}: no finished stage 06 (no {joint / 'manifest.json'}); run "
                           f"`make all SCENE=...` (or `make 06_joint_opt`) first")
    params_file = folder / ".params" / "06_joint_opt.json"
    if not params_file.is_file():
        raise GlimpseError(f"{params_file}: missing; the run folder is incomplete (rerun stage 06)")
    params = json.loads(params_file.read_text())["params"]
    # runs finished before people could have their own body model file recorded none
    body = config_from_mapping(BodyConfig, {"person_model_paths": [], **params["body"]}, "body")
    body_models = BodyModels.load(body)
    width, height, cameras = read_cameras_json(sfm / "cameras.json")
    background = GaussianModel.from_splats(read_gaussians_ply(joint / "background.ply")[0])
    return FinishedRun(folder, width, height, cameras, background,
                       load_trained_people(joint / "humans", body_models), body_models,
                       config_from_mapping(RenderConfig, params["render"], "render"))


def default_frame(run: FinishedRun) -> int:
    """The middle input frame with a camera."""
    frames = sorted(run.cameras)
    if not frames:
        raise GlimpseError(f"{run.folder / '01_sfm' / 'cameras.json'}: no camera, no frame")
    return frames[len(frames) // 2]
