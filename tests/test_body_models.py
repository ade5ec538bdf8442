"""Each person's body model (glimpse.body.models.BodyModels): the shared file unless body.person_model_paths
gives a person their own (gendered SMPL), every file read once, one topology for everyone."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import torch

from glimpse.body.config import BodyConfig, SkinningConfig
from glimpse.body.models import BodyModels
from glimpse.errors import GlimpseError
from tests.body_files import random_smpl_arrays


def write_variant(path, seed: int, template_scale: float = 1.0, faces_from: dict | None = None) -> dict:
    """A random SMPL-format pickle; ``faces_from`` gives it another model's faces (the same topology)."""
    arrays = random_smpl_arrays(seed)
    arrays["v_template"] = arrays["v_template"] * template_scale
    if faces_from is not None:
        arrays["f"] = faces_from["f"]
    with open(path, "wb") as handle:
        pickle.dump(arrays, handle, protocol=2)
    return arrays


def config(shared, own: list[str]) -> BodyConfig:
    return BodyConfig(str(shared), own, 30.0, SkinningConfig(30, 1.0, 64, 0.1))


def test_each_person_gets_their_own_model_and_everyone_else_the_shared_one(tmp_path):
    female = write_variant(tmp_path / "SMPL_FEMALE.pkl", seed=1)
    male = write_variant(tmp_path / "SMPL_MALE.pkl", seed=2, template_scale=1.1, faces_from=female)
    models = BodyModels.load(config(tmp_path / "SMPL_FEMALE.pkl",
                                    [f"p1={tmp_path / 'SMPL_MALE.pkl'}", f"p2={tmp_path / 'SMPL_MALE.pkl'}"]),
                             dtype=torch.float64)
    assert models["p0"] is models.default and models["someone"] is models.default
    assert models["p1"] is models["p2"] and models["p1"] is not models.default  # one file, read once
    assert np.allclose(models["p1"].v_template.numpy(), male["v_template"])
    assert np.allclose(models["p0"].v_template.numpy(), female["v_template"])
    assert torch.equal(models.faces, models["p1"].faces)
    zeros = torch.zeros(1, 3, dtype=torch.float64), torch.zeros(1, 69, dtype=torch.float64)
    betas = torch.zeros(1, 10, dtype=torch.float64)
    posed = {pid: models[pid](betas, *zeros).vertices[0] for pid in ("p0", "p1")}
    assert not torch.allclose(posed["p0"], posed["p1"])  # the same parameters pose two different bodies


def test_a_persons_model_of_another_topology_is_refused_naming_the_person(tmp_path):
    write_variant(tmp_path / "SMPL_FEMALE.pkl", seed=1)
    write_variant(tmp_path / "OTHER.pkl", seed=2)  # its own random faces
    with pytest.raises(GlimpseError, match=r"body.person_model_paths \(p1\): .*OTHER.pkl does not share the topology"):
        BodyModels.load(config(tmp_path / "SMPL_FEMALE.pkl", [f"p1={tmp_path / 'OTHER.pkl'}"]))
