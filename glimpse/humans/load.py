"""Reading stage 06's people back: canonical.ply, skinning.npz and body.npz of each person."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from glimpse.body.models import BodyModels
from glimpse.body.params import read_body_params
from glimpse.body.skinning import SkinWeightGrid
from glimpse.errors import GlimpseError
from glimpse.gaussians.model import GaussianModel
from glimpse.gaussians.ply import read_gaussians_ply
from glimpse.humans.person import PersonGaussians, build_rig


def load_trained_people(humans_dir: Path, body_models: BodyModels,
                        between_frames: Iterable[int] = ()) -> list[PersonGaussians]:
    """Every person under ``humans_dir`` (stage 06's ``humans/``), in pid order, posed by the refined poses
    of body.npz (pose offsets start at zero), frozen for rendering (PersonGaussians.freeze); ``body_models``
    gives each person's body model. The Da-pose angle is the one stage 06 trained with. ``between_frames``:
    frames to pose each person at too where they fall between two of that person's frames (held-out frames
    of the input video; BodyParams.with_frames_between)."""
    people: list[PersonGaussians] = []
    if not humans_dir.is_dir():  # stage 06 trained nobody (no person had a body in a frame with a camera)
        return people
    for folder in sorted(p for p in humans_dir.iterdir() if p.is_dir()):
        splats, metadata = read_gaussians_ply(folder / "canonical.ply")
        if "canonical_hip_angle_deg" not in metadata:
            raise GlimpseError(f"{folder / 'canonical.ply'}: no canonical_hip_angle_deg comment; rerun stage 06")
        with np.load(folder / "skinning.npz", allow_pickle=False) as data:
            grid = SkinWeightGrid.from_npz_dict(dict(data), str(folder / "skinning.npz"))
        body = read_body_params(folder / "body.npz").with_frames_between(list(between_frames))
        rig = build_rig(body_models[folder.name], body.betas, float(metadata["canonical_hip_angle_deg"]))
        people.append(PersonGaussians(folder.name, GaussianModel.from_splats(splats), grid, rig, body).freeze())
    return people
