"""Skinning of canonical Gaussians (IDW weights, baked grid, deformation, Da-pose)."""

import numpy as np
import pytest
import torch

from glimpse.body.model import BodyModel
from glimpse.body.motion import builtin_motion
from glimpse.body.skinning import (
    SkinWeightGrid, bake_skin_weight_grid, canonical_body_pose, deform_gaussians,
    canonical_to_posed, idw_skin_weights,
)
from glimpse.config import REPO_ROOT

FREE_BODY = REPO_ROOT / "glimpse" / "body" / "assets" / "free_body.npz"
F64 = torch.float64


@pytest.fixture(scope="module")
def body():
    """The free body in the canonical Da-pose and posed in a walking frame, with both transforms."""
    model = BodyModel.from_file(FREE_BODY, dtype=F64)
    zeros = torch.zeros(1, 10, dtype=F64)
    canonical = model(zeros, torch.zeros(1, 3, dtype=F64), torch.as_tensor(canonical_body_pose(30.0))[None])
    walk = builtin_motion("walk", n_frames=12, fps=12)
    frame = 5
    target = model(zeros, torch.as_tensor(walk.global_orient[frame : frame + 1]),
                   torch.as_tensor(walk.body_pose[frame : frame + 1]), torch.as_tensor(walk.transl[frame : frame + 1]),
                   scale=torch.tensor([1.3], dtype=F64))
    return model, canonical, target, (target.transforms[0], canonical.transforms[0])


@pytest.fixture(scope="module")
def grid(body):
    model, canonical, _, _ = body
    return bake_skin_weight_grid(canonical.vertices[0].numpy(), model.data.weights, resolution=64, margin=0.1,
                                 k=30, power=1.0)


def test_idw_weights_are_normalised_and_exact_on_vertices():
    rng = np.random.default_rng(0)
    vertices = rng.normal(size=(200, 3))
    weights = rng.dirichlet(np.ones(24), size=200)
    points = np.concatenate([vertices[:10], rng.normal(size=(50, 3))])
    result = idw_skin_weights(points, vertices, weights, k=8, power=1.0)
    assert np.allclose(result.sum(1), 1) and (result >= 0).all()
    assert np.allclose(result[:10], weights[:10])
    nearest = idw_skin_weights(points, vertices, weights, k=1, power=1.0)  # the official code's choice
    dist = np.linalg.norm(points[:, None] - vertices[None], axis=-1)
    assert np.allclose(nearest, weights[dist.argmin(1)])


def test_a_point_on_a_vertex_moves_exactly_as_that_vertex(body):
    model, canonical, target, transforms = body  # the free body has no pose correctives (SMPL's add to this)
    vertices = canonical.vertices[0]
    weights = torch.as_tensor(idw_skin_weights(vertices.numpy(), vertices.numpy(), model.data.weights, 30, 1.0))
    moved, _ = deform_gaussians(vertices, torch.eye(3, dtype=F64).expand(len(vertices), 3, 3),
                                canonical_to_posed(weights, *transforms))
    assert torch.allclose(moved, target.vertices[0], atol=1e-9)
    # GTU's blend of relative transforms (sum_j w_j P_j C_j^-1) moves hip-region vertices off the body
    posed, canon = transforms
    gtu = torch.einsum("nj,jab->nab", weights, posed @ torch.linalg.inv(canon))
    gtu_moved, _ = deform_gaussians(vertices, torch.eye(3, dtype=F64).expand(len(vertices), 3, 3), gtu)
    assert float((gtu_moved - target.vertices[0]).norm(dim=-1).max()) > 0.005


def test_covariances_stay_symmetric_positive_definite(body):
    model, canonical, _, transforms = body
    rng = np.random.default_rng(1)
    means = canonical.vertices[0][rng.integers(0, model.num_vertices, 500)]
    A = torch.as_tensor(rng.normal(size=(500, 3, 3)))
    covariances = A @ A.transpose(1, 2) * 1e-4 + 1e-8 * torch.eye(3, dtype=F64)
    weights = torch.as_tensor(idw_skin_weights(means.numpy(), canonical.vertices[0].numpy(), model.data.weights, 30, 1.0))
    _, posed = deform_gaussians(means, covariances, canonical_to_posed(weights, *transforms))
    assert torch.allclose(posed, posed.transpose(1, 2), atol=1e-15)
    assert (torch.linalg.eigvalsh(posed) > 0).all()
    # the blended matrix carries the person's scale: volumes grow by about scale^3
    ratio = torch.linalg.det(posed) / torch.linalg.det(covariances)
    assert float(ratio.median()) == pytest.approx(1.3**6, rel=0.05)


def test_grid_lookup_matches_direct_idw(body, grid):
    """Tolerances (64^3 grid over the 2.2 m Da-pose cube, 3.5 cm voxels), for points within 1 cm of
    the body: skin weights differ by a mean L1 distance under 0.05 (p99 < 0.45, at finger and toe
    tips); after posing (walk frame, scale 1.3) positions differ by a mean under 3 mm, p99 under 2 cm."""
    model, canonical, _, transforms = body
    vertices = canonical.vertices[0].numpy()
    corners = torch.stack(torch.meshgrid(*[torch.linspace(0, 1, 64, dtype=F64)] * 3, indexing="ij"), -1)[::9, ::9, ::9]
    nodes = (grid.bounds_min + corners.reshape(-1, 3).flip(-1).float() * (grid.bounds_max - grid.bounds_min))
    exact = idw_skin_weights(nodes.double().numpy(), vertices, model.data.weights, 30, 1.0)
    assert np.abs(grid.lookup(nodes).numpy() - exact).max() < 1e-5  # trilinear is exact on the nodes

    rng = np.random.default_rng(2)
    points = vertices[rng.integers(0, len(vertices), 5000)] + rng.normal(0, 0.01, (5000, 3))
    direct = idw_skin_weights(points, vertices, model.data.weights, 30, 1.0)
    looked = grid.lookup(torch.as_tensor(points, dtype=torch.float32)).double()
    l1 = np.abs(direct - looked.numpy()).sum(1)
    assert l1.mean() < 0.05 and np.quantile(l1, 0.99) < 0.45, (l1.mean(), np.quantile(l1, 0.99))
    eye = torch.eye(3, dtype=F64).expand(len(points), 3, 3)
    p_direct, _ = deform_gaussians(torch.as_tensor(points), eye, canonical_to_posed(torch.as_tensor(direct), *transforms))
    p_grid, _ = deform_gaussians(torch.as_tensor(points), eye, canonical_to_posed(looked, *transforms))
    error = (p_direct - p_grid).norm(dim=-1)
    assert float(error.mean()) < 0.003 and float(error.quantile(0.99)) < 0.02, (error.mean(), error.quantile(0.99))
    coarser = bake_skin_weight_grid(vertices, model.data.weights, 40, 0.1, 30, 1.0)
    l1_coarser = np.abs(direct - coarser.lookup(torch.as_tensor(points, dtype=torch.float32)).numpy()).sum(1)
    assert l1_coarser.mean() > l1.mean()  # converges with resolution


def test_grid_covers_the_body_with_its_margin_and_round_trips(body, grid, tmp_path):
    _, canonical, _, _ = body
    vertices = canonical.vertices[0].float()
    assert grid.inside(vertices).all()
    assert grid.inside(vertices + torch.tensor([0.0, 0.0, 0.09])).all()  # 9 cm of loose clothing in front
    assert not grid.inside(torch.tensor([[5.0, 0.0, 0.0]])).any()
    np.savez(tmp_path / "skinning.npz", **grid.to_npz_dict())
    loaded = SkinWeightGrid.from_npz_dict(dict(np.load(tmp_path / "skinning.npz")))
    assert torch.equal(loaded.weights, grid.weights) and torch.equal(loaded.bounds_min, grid.bounds_min)


def test_da_pose_spreads_the_legs_and_relative_transforms_are_identity_at_rest(body):
    model, canonical, _, _ = body
    pose = canonical_body_pose(30.0)
    assert np.count_nonzero(pose) == 2 and pose[2] > 0 > pose[5]
    j = canonical.joints[0]
    for hip, ankle, side in ((1, 7, 1), (2, 8, -1)):
        spread = side * (j[ankle, 0] - j[hip, 0])
        assert spread == pytest.approx(float((j[hip, 1] - j[ankle, 1]) * np.tan(np.radians(30.0))), rel=0.05)
    weights = torch.as_tensor(np.random.default_rng(3).dirichlet(np.ones(24), size=50))
    same = canonical_to_posed(weights, canonical.transforms[0], canonical.transforms[0])
    assert torch.allclose(same, torch.eye(4, dtype=F64).expand_as(same), atol=1e-12)
