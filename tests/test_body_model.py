"""SMPL body model layer: agreement with smplx and body_models, scale/transl contract,
skinning transforms, gradients, chumpy-free loading of official pickles, clear errors."""

from __future__ import annotations

import os
import pickle
import sys

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from glimpse.body.lbs import batch_rigid_transform, batch_rodrigues, blend_shapes, skew, vertices_to_joints
from glimpse.body.model import BodyModel, BodyOutput
from glimpse.body.model_file import (
    BODY_MODEL_FORMAT,
    JOINT_NAMES,
    NUM_JOINTS,
    SMPL_PARENTS,
    BodyModelData,
    BodyModelFileError,
    load_body_model_file,
)
from glimpse.errors import GlimpseError
from tests.body_files import random_smpl_arrays, write_random_smpl_npz, write_random_smpl_pkl

SEED = 7
BATCH = 4
REFERENCE_TOL_M = 1e-5
BETA_STD = 1.0
BODY_POSE_STD_RAD = 0.4  # realistic joint rotations
TRANSL_STD_M = 2.0


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    root = tmp_path_factory.mktemp("body_models")
    return {
        "chumpy_pkl": write_random_smpl_pkl(root / "SMPL_NEUTRAL.pkl", SEED, chumpy_style=True),
        "plain_pkl": write_random_smpl_pkl(root / "plain.pkl", SEED, chumpy_style=False),
        "npz": write_random_smpl_npz(root / "model.npz", SEED),
        "root": root,
    }


@pytest.fixture(scope="module")
def model64(files) -> BodyModel:
    return BodyModel.from_file(files["npz"], dtype=torch.float64)


def random_params(batch: int, seed: int, dtype=torch.float64) -> dict[str, torch.Tensor]:
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=(batch, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    global_orient = axis * rng.uniform(0.0, np.pi, size=(batch, 1))
    params = {
        "betas": rng.normal(scale=BETA_STD, size=(batch, 10)),
        "global_orient": global_orient,
        "body_pose": rng.normal(scale=BODY_POSE_STD_RAD, size=(batch, 69)),
        "transl": rng.normal(scale=TRANSL_STD_M, size=(batch, 3)),
    }
    return {k: torch.tensor(v, dtype=dtype) for k, v in params.items()}


def tiny_data(num_vertices: int = 30, seed: int = 3, num_shape: int = 10) -> BodyModelData:
    a = random_smpl_arrays(seed, num_vertices=num_vertices, num_shape=num_shape, num_faces=16)
    return BodyModelData(
        kind="smpl",
        v_template=a["v_template"],
        shapedirs=a["shapedirs"],
        posedirs=a["posedirs"],
        J_regressor=a["J_regressor"],
        weights=a["weights"],
        parents=np.array(SMPL_PARENTS),
        faces=a["f"],
    )


# --------------------------------------------------------------------------- (a) references


def test_agrees_with_smplx(files, model64):
    smplx = pytest.importorskip("smplx")
    p = random_params(BATCH, seed=11)
    ours = model64(**p)
    reference = smplx.SMPL(model_path=str(files["plain_pkl"]), dtype=torch.float64, batch_size=BATCH)
    with torch.no_grad():
        ref = reference(**p)
    assert ours.vertices.shape == (BATCH, 6890, 3) and ours.joints.shape == (BATCH, NUM_JOINTS, 3)
    assert (ours.vertices - ref.vertices).abs().max() < REFERENCE_TOL_M
    assert (ours.joints - ref.joints[:, :NUM_JOINTS]).abs().max() < REFERENCE_TOL_M
    np.testing.assert_array_equal(model64.faces.numpy(), reference.faces.astype(np.int64))


def test_agrees_with_body_models(files, model64):
    smpl_module = pytest.importorskip("body_models.smpl.torch")
    p = random_params(BATCH, seed=12)
    ours = model64(**p)
    for path in (files["npz"], files["plain_pkl"]):
        reference = smpl_module.SMPL(model_path=path).double()
        kwargs = {
            "pelvis_rotation": p["global_orient"],
            "shape": p["betas"],
            "global_translation": p["transl"],
        }
        body_pose = p["body_pose"].reshape(BATCH, 23, 3)
        with torch.no_grad():
            vertices = reference.forward_vertices(body_pose, **kwargs)
            joints = reference.forward_skeleton(body_pose, **kwargs)[..., :3, 3]
        assert (ours.vertices - vertices).abs().max() < REFERENCE_TOL_M
        assert (ours.joints - joints).abs().max() < REFERENCE_TOL_M


def test_rest_pose_outputs(model64):
    zeros = torch.zeros(2, 69, dtype=torch.float64)
    out = model64(torch.zeros(10), torch.zeros(2, 3), zeros)
    template = model64.v_template.expand(2, -1, -1)
    torch.testing.assert_close(out.vertices, template, rtol=0, atol=1e-12)
    torch.testing.assert_close(out.rest_vertices, template, rtol=0, atol=0)
    torch.testing.assert_close(out.joints, out.rest_joints, rtol=0, atol=1e-12)
    eye = torch.eye(4, dtype=torch.float64).expand(2, NUM_JOINTS, 4, 4)
    torch.testing.assert_close(out.transforms, eye, rtol=0, atol=1e-12)


def test_float32_default_close_to_float64(files, model64):
    model32 = BodyModel.from_file(files["npz"])
    assert model32.dtype == torch.float32 and model32.kind == "smpl" and model32.num_vertices == 6890
    assert not list(model32.parameters()), "model arrays must be buffers, not parameters"
    p = random_params(BATCH, seed=13)
    out32 = model32(**{k: v.float() for k, v in p.items()})
    out64 = model64(**p)
    assert out32.vertices.dtype == torch.float32
    assert (out32.vertices.double() - out64.vertices).abs().max() < 1e-5


# --------------------------------------------------------------------------- (b) scale, (c) transforms


def test_scale_and_transl_contract(model64):
    p = random_params(BATCH, seed=14)
    scale = torch.tensor([0.5, 1.0, 1.3, 2.0], dtype=torch.float64)
    base = model64(p["betas"], p["global_orient"], p["body_pose"])
    out = model64(**p, scale=scale)
    s, t = scale[:, None, None], p["transl"][:, None, :]
    torch.testing.assert_close(out.vertices, s * base.vertices + t, rtol=0, atol=1e-12)
    torch.testing.assert_close(out.joints, s * base.joints + t, rtol=0, atol=1e-12)
    torch.testing.assert_close(out.rest_vertices, base.rest_vertices)  # rest outputs are pre-transform
    scalar = model64(**p, scale=1.7)
    torch.testing.assert_close(scalar.vertices, 1.7 * base.vertices + t, rtol=0, atol=1e-12)


def test_transforms_reproduce_vertices_and_joints(model64):
    p = random_params(BATCH, seed=15)
    out = model64(**p, scale=torch.tensor([0.9, 1.1, 1.0, 1.4], dtype=torch.float64))
    rest_h = torch.cat([out.rest_vertices, torch.ones_like(out.rest_vertices[..., :1])], dim=-1)  # [B, V, 4]
    blended = torch.einsum("vj,bjkl->bvkl", model64.weights, out.transforms)  # [B, V, 4, 4]
    skinned = (blended @ rest_h[..., None])[..., :3, 0]
    torch.testing.assert_close(skinned, out.vertices, rtol=0, atol=1e-10)
    rest_joints_h = torch.cat([out.rest_joints, torch.ones_like(out.rest_joints[..., :1])], dim=-1)
    moved = (out.transforms @ rest_joints_h[..., None])[..., :3, 0]
    torch.testing.assert_close(moved, out.joints, rtol=0, atol=1e-10)


# --------------------------------------------------------------------------- (d) gradients


def test_gradients_reach_every_input(files):
    model = BodyModel.from_file(files["npz"])
    for pose_scale in (1.0, 0.0):  # also at the zero pose (Rodrigues at angle 0)
        p = {k: v.float().requires_grad_(True) for k, v in random_params(2, seed=16).items()}
        p["body_pose"] = (p["body_pose"].detach() * pose_scale).requires_grad_(True)
        p["global_orient"] = (p["global_orient"].detach() * pose_scale).requires_grad_(True)
        scale = torch.tensor([1.0, 1.2], requires_grad=True)
        out = model(**p, scale=scale)
        weights_v = torch.linspace(0.5, 1.5, 3)  # break the symmetry of a plain sum
        loss = (out.vertices * weights_v).pow(2).sum() + (out.joints * weights_v).sum()
        loss.backward()
        for name, tensor in [*p.items(), ("scale", scale)]:
            assert tensor.grad is not None, name
            assert torch.isfinite(tensor.grad).all(), name
            assert tensor.grad.abs().sum() > 0, name


def test_gradcheck_tiny_model():
    model = BodyModel(tiny_data(), dtype=torch.float64)
    p = random_params(2, seed=17)
    inputs = (
        p["betas"].requires_grad_(),
        p["global_orient"].requires_grad_(),
        p["body_pose"].requires_grad_(),
        p["transl"].requires_grad_(),
        torch.tensor([0.8, 1.3], dtype=torch.float64, requires_grad=True),
    )

    def forward(*args):
        out = model(*args)
        return out.vertices, out.joints, out.transforms

    assert torch.autograd.gradcheck(forward, inputs, eps=1e-6, atol=1e-7)


# --------------------------------------------------------------------------- lbs maths


def test_batch_rodrigues_matches_scipy_and_is_exact_at_zero():
    rng = np.random.default_rng(18)
    vectors = np.concatenate(
        [rng.normal(size=(50, 3)), rng.normal(scale=1e-3, size=(5, 3)), rng.normal(scale=1e-8, size=(5, 3))]
    )
    ours = batch_rodrigues(torch.tensor(vectors))
    np.testing.assert_allclose(ours.numpy(), Rotation.from_rotvec(vectors).as_matrix(), atol=1e-14)
    zero = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    assert torch.equal(batch_rodrigues(zero), torch.eye(3, dtype=torch.float64))
    jacobian = torch.autograd.functional.jacobian(batch_rodrigues, zero)  # [3, 3, 3]
    torch.testing.assert_close(jacobian, skew(torch.eye(3, dtype=torch.float64)).permute(1, 2, 0))
    batched = batch_rodrigues(torch.tensor(vectors).reshape(5, 12, 3))
    assert batched.shape == (5, 12, 3, 3)
    float32 = batch_rodrigues(torch.tensor(vectors, dtype=torch.float32))
    assert (float32.double() - ours).abs().max() < 1e-6


def test_batch_rodrigues_gradcheck_near_zero():
    vectors = torch.tensor(
        [[0.0, 0.0, 0.0], [1e-4, -2e-4, 3e-5], [5e-3, 6e-3, -1e-3], [0.3, -1.2, 2.0]], dtype=torch.float64
    ).requires_grad_()
    assert torch.autograd.gradcheck(batch_rodrigues, (vectors,))
    assert torch.autograd.gradgradcheck(batch_rodrigues, (vectors,))


def test_lbs_building_blocks():
    rng = np.random.default_rng(19)
    betas = torch.tensor(rng.normal(size=(2, 4)))
    basis = torch.tensor(rng.normal(size=(5, 3, 4)))
    torch.testing.assert_close(blend_shapes(betas, basis), torch.einsum("bs,vcs->bvc", betas, basis))
    regressor = torch.tensor(rng.uniform(size=(3, 5)))
    vertices = torch.tensor(rng.normal(size=(2, 5, 3)))
    torch.testing.assert_close(vertices_to_joints(regressor, vertices), regressor @ vertices)
    # a two-joint chain: the child's transform maps rest points to posed points
    rot = torch.tensor(Rotation.from_rotvec(rng.normal(size=(1, 2, 3)).reshape(2, 3)).as_matrix())[None]
    joints = torch.tensor([[[0.1, 0.2, 0.3], [0.1, 1.2, 0.3]]], dtype=torch.float64)
    posed, transforms = batch_rigid_transform(rot, joints, [-1, 0])
    expected_child = joints[0, 0] + rot[0, 0] @ (joints[0, 1] - joints[0, 0])
    torch.testing.assert_close(posed[0, 1], expected_child)
    torch.testing.assert_close(posed[0, 0], joints[0, 0])
    point = torch.tensor([0.3, 1.5, 0.3], dtype=torch.float64)
    expected_point = expected_child + rot[0, 0] @ rot[0, 1] @ (point - joints[0, 1])
    torch.testing.assert_close((transforms[0, 1] @ torch.cat([point, torch.ones(1, dtype=torch.float64)]))[:3],
                               expected_point)
    with pytest.raises(ValueError, match="parents"):
        batch_rigid_transform(rot, joints, [0, 0])


# --------------------------------------------------------------------------- (e) official pkl


def test_official_chumpy_pickle_loads_without_chumpy(files):
    assert "chumpy" not in sys.modules
    data = load_body_model_file(files["chumpy_pkl"])
    assert "chumpy" not in sys.modules and "chumpy.ch" not in sys.modules
    reference = load_body_model_file(files["npz"])
    for key in ("v_template", "shapedirs", "posedirs", "J_regressor", "weights", "parents", "faces"):
        np.testing.assert_array_equal(getattr(data, key), getattr(reference, key), err_msg=key)
    assert data.kind == "smpl" and data.parents[0] == -1 and data.parents.dtype == np.int64
    assert data.J_regressor.shape == (NUM_JOINTS, 6890) and isinstance(data.J_regressor, np.ndarray)
    assert sorted(data.extras) == ["J", "J_regressor_prior", "vert_sym_idxs", "weights_prior"]
    assert not data.v_template.flags.writeable and not data.extras["J"].flags.writeable
    assert len(JOINT_NAMES) == NUM_JOINTS == len(SMPL_PARENTS)
    out = BodyModel(data)(torch.zeros(10), torch.zeros(1, 3), torch.zeros(1, 69))
    assert isinstance(out, BodyOutput)


@pytest.mark.parametrize("protocol", [0, 2])
def test_small_chumpy_pickles_of_any_protocol(tmp_path, protocol):
    path = write_random_smpl_pkl(tmp_path / "m.pkl", 5, chumpy_style=True, num_vertices=40, protocol=protocol)
    data = load_body_model_file(path)
    assert data.v_template.shape == (40, 3) and data.shapedirs.shape == (40, 3, 10)
    assert "chumpy" not in sys.modules


def test_free_npz_with_extras_and_flat_posedirs(tmp_path):
    arrays = random_smpl_arrays(2, num_vertices=50)
    path = write_random_smpl_npz(
        tmp_path / "free.npz",
        2,
        num_vertices=50,
        body_model="free",
        format=BODY_MODEL_FORMAT,
        keypoint_map=np.eye(3),
        landmark_names=np.array(["nose", "chin"]),
        posedirs=arrays["posedirs"].reshape(150, 207),
    )
    data = load_body_model_file(path)
    assert data.kind == "free" and sorted(data.extras) == ["keypoint_map", "landmark_names"]
    assert data.extras["landmark_names"].tolist() == ["nose", "chin"]
    np.testing.assert_array_equal(data.posedirs, arrays["posedirs"])
    with pytest.raises((TypeError, ValueError)):
        data.extras["keypoint_map"][0, 0] = 2.0
    with pytest.raises(TypeError):
        data.extras["other"] = np.zeros(1)


def test_many_shape_components(tmp_path):
    path = write_random_smpl_npz(tmp_path / "s300.npz", 4, num_vertices=30, num_shape=300)
    data = load_body_model_file(path)
    assert data.shapedirs.shape == (30, 3, 300)
    model = BodyModel(data, num_betas=300, dtype=torch.float64)
    out = model(torch.zeros(300), torch.zeros(1, 3), torch.zeros(1, 69))
    assert out.vertices.shape == (1, 30, 3)
    ten = BodyModel(data, dtype=torch.float64)(torch.ones(10), torch.zeros(1, 3), torch.zeros(1, 69))
    expected = data.v_template + data.shapedirs[:, :, :10].sum(axis=2)
    np.testing.assert_allclose(ten.vertices[0].numpy(), expected, atol=1e-12)


# --------------------------------------------------------------------------- (f) errors


def _npz_error(tmp_path, **entries) -> str:
    path = write_random_smpl_npz(tmp_path / "bad.npz", 1, num_vertices=30, **entries)
    with pytest.raises(BodyModelFileError) as info:
        load_body_model_file(path)
    message = str(info.value)
    assert str(path) in message and isinstance(info.value, (GlimpseError, ValueError))
    return message


def test_missing_key_error(tmp_path):
    assert "missing key(s) weights" in _npz_error(tmp_path, weights=None)


def test_wrong_shape_errors(tmp_path):
    assert "shapedirs must be [30, 3, *]" in _npz_error(tmp_path, shapedirs=np.zeros((29, 3, 10)))
    assert "at least 10" in _npz_error(tmp_path, shapedirs=np.zeros((30, 3, 5)))
    assert "v_template must be [*, 3]" in _npz_error(tmp_path, v_template=np.zeros((30, 2)))
    assert "posedirs" in _npz_error(tmp_path, posedirs=np.zeros((30, 3, 200)))
    assert "J_regressor must be [24, 30]" in _npz_error(tmp_path, J_regressor=np.zeros((23, 30)))
    assert "face indices" in _npz_error(tmp_path, f=np.array([[0, 1, 30]]))


def test_nan_error(tmp_path):
    v = random_smpl_arrays(1, num_vertices=30)["v_template"].copy()
    v[3, 1] = np.nan
    assert "v_template holds 1 NaN" in _npz_error(tmp_path, v_template=v)


def test_kintree_format_kind_and_weight_errors(tmp_path):
    kintree = random_smpl_arrays(1, num_vertices=30)["kintree_table"].copy()
    kintree[0, 5] = 3
    assert "not SMPL's 24-joint tree" in _npz_error(tmp_path, kintree_table=kintree)
    assert "kintree_table must be [2, 24]" in _npz_error(tmp_path, kintree_table=np.zeros((2, 22), dtype=int))
    assert "integer joint indices" in _npz_error(tmp_path, kintree_table=np.full((2, 24), "a"))
    assert "faces must hold integer vertex indices" in _npz_error(tmp_path, f=np.full((3, 3), "a"))
    assert "unknown format 'glimpse-body/9'" in _npz_error(tmp_path, format="glimpse-body/9")
    assert "body_model must be one of" in _npz_error(tmp_path, body_model="smplx")
    assert "must sum to 1" in _npz_error(tmp_path, weights=np.full((30, 24), 0.5))


def test_disallowed_pickle_class_is_refused(tmp_path):
    marker = tmp_path / "pwned"

    class Exploit:
        def __reduce__(self):
            return (os.system, (f"touch {marker}",))

    path = tmp_path / "evil.pkl"
    with open(path, "wb") as handle:
        pickle.dump({"v_template": Exploit()}, handle, protocol=2)
    with pytest.raises(BodyModelFileError, match=r"refusing to unpickle \w+\.system") as info:
        load_body_model_file(path)
    assert str(path) in str(info.value)
    assert not marker.exists()


def test_file_level_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="not found"):
        load_body_model_file(tmp_path / "nope.pkl")
    (tmp_path / "model.obj").write_text("v 0 0 0\n")
    with pytest.raises(BodyModelFileError, match="expected .pkl or .npz"):
        load_body_model_file(tmp_path / "model.obj")
    (tmp_path / "broken.pkl").write_bytes(b"\x80\x02}q\x00(X")
    with pytest.raises(BodyModelFileError, match="not a readable model pickle"):
        load_body_model_file(tmp_path / "broken.pkl")
    with open(tmp_path / "list.pkl", "wb") as handle:
        pickle.dump([1, 2], handle)
    with pytest.raises(BodyModelFileError, match="expected a dict"):
        load_body_model_file(tmp_path / "list.pkl")


def test_forward_input_errors():
    model = BodyModel(tiny_data())
    ok = (torch.zeros(2, 10), torch.zeros(2, 3), torch.zeros(2, 69))
    with pytest.raises(ValueError, match="body_pose must be"):
        model(ok[0], ok[1], torch.zeros(2, 66))
    with pytest.raises(ValueError, match="global_orient must be"):
        model(ok[0], torch.zeros(2, 4), ok[2])
    with pytest.raises(ValueError, match="betas must be"):
        model(torch.zeros(3, 10), ok[1], ok[2])
    with pytest.raises(ValueError, match="transl must be"):
        model(*ok, transl=torch.zeros(2, 2))
    with pytest.raises(ValueError, match="scale must be"):
        model(*ok, scale=torch.ones(3))
    with pytest.raises(ValueError, match="num_betas"):
        BodyModel(tiny_data(), num_betas=11)
    out = model(torch.zeros(10), ok[1], torch.zeros(2, 23, 3), transl=torch.zeros(3))
    assert out.vertices.shape == (2, 30, 3)
