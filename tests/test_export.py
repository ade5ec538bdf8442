"""Exports: SH rotation against evaluation at rotated directions, covariances back to scales and
rotations, and a posed person written as a standard 3DGS PLY that renders like the run."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from glimpse.body.config import BodyConfig, resolve_model_path
from glimpse.body.model import BodyModel
from glimpse.body.params import BodyParams
from glimpse.config import config_from_mapping, load_pipeline_yaml
from glimpse.export.splats import (
    concatenate,
    covariance_to_scales_quats,
    frame_splats,
    rotate_sh,
    with_sh_degree,
)
from glimpse.gaussians.model import GaussianModel
from glimpse.gaussians.ply import read_gaussians_ply, write_gaussians_ply
from glimpse.humans.compose import frame_gaussians, render_frame
from glimpse.humans.person import initial_person
from glimpse.render import Camera, rasterize
from glimpse.render.config import RenderConfig
from glimpse.render.projection import quat_scale_to_covariance
from glimpse.render.sh import rotate_view_dirs, sh_to_rgb

BODY = config_from_mapping(BodyConfig, load_pipeline_yaml()["body"], "body")
RENDER = RenderConfig(backend="cpu", sh_degree=3, antialiased=False)


def _rotations(count: int, seed: int) -> torch.Tensor:
    q = torch.nn.functional.normalize(torch.randn(count, 4, generator=torch.Generator().manual_seed(seed),
                                                  dtype=torch.float64), dim=1)
    w, x, y, z = q.unbind(1)
    return torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], 1).reshape(-1, 3, 3)


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_rotated_sh_seen_from_the_world_match_the_canonical_sh_at_rotated_directions(degree):
    generator = torch.Generator().manual_seed(degree)
    count = 50
    sh = torch.randn(count, (degree + 1) ** 2, 3, generator=generator, dtype=torch.float64)
    rotations = _rotations(count, degree)
    dirs = torch.randn(count, 3, generator=generator, dtype=torch.float64)
    expected = sh_to_rgb(degree, sh, rotate_view_dirs(dirs, rotations))  # how stage 06 renders a posed person
    got = sh_to_rgb(degree, rotate_sh(sh, rotations), dirs)
    torch.testing.assert_close(got, expected, atol=1e-9, rtol=0)
    torch.testing.assert_close(rotate_sh(sh, torch.eye(3, dtype=torch.float64).expand(count, 3, 3)), sh)


def test_covariances_go_back_to_scales_and_rotations():
    generator = torch.Generator().manual_seed(0)
    scales = torch.rand(40, 3, generator=generator, dtype=torch.float64) * 0.1 + 1e-3
    quats = torch.randn(40, 4, generator=generator, dtype=torch.float64)
    covariances = quat_scale_to_covariance(quats, scales)
    back_scales, back_quats = covariance_to_scales_quats(covariances)
    torch.testing.assert_close(quat_scale_to_covariance(back_quats, back_scales), covariances, atol=1e-12, rtol=0)
    torch.testing.assert_close(back_scales.sort(dim=1).values, scales.sort(dim=1).values)


def test_a_posed_person_exported_as_3dgs_renders_like_the_run(tmp_path):
    body_model = BodyModel.from_file(resolve_model_path(BODY))
    rng = np.random.default_rng(0)
    body = BodyParams(np.array([0, 1]), rng.normal(0, 0.5, 10), np.array([[np.pi, 0.3, 0.0]] * 2),
                      rng.normal(0, 0.3, (2, 69)), np.array([[0.0, 0.2, 3.0]] * 2), 1.0, "free", np.zeros(2, bool))
    person = initial_person("p0", body_model, body, 30.0, BODY.skinning, 0.5, 0.9, 3, 3)
    generator = torch.Generator().manual_seed(1)
    with torch.no_grad():  # anisotropic, rotated, coloured differently from every side
        person.model.log_scales.add_(torch.randn(person.model.log_scales.shape, generator=generator) * 0.5)
        person.model.quats.copy_(torch.randn(person.model.quats.shape, generator=generator))
        person.model.sh_dc.add_(torch.randn(person.model.sh_dc.shape, generator=generator) * 0.5)
        person.model.sh_rest.copy_(torch.randn(person.model.sh_rest.shape, generator=generator) * 0.3)
    camera = Camera(torch.tensor([[90.0, 0, 39.5], [0, 90.0, 59.5], [0, 0, 1]]), torch.eye(3), torch.zeros(3), 80, 120)
    with torch.no_grad():
        run = render_frame(camera, frame_gaussians(camera, 1, [person], 3), 1, RENDER, torch.zeros(3)).rgb
    write_gaussians_ply(tmp_path / "posed.ply", frame_splats(None, [person], 1))
    splats, _ = read_gaussians_ply(tmp_path / "posed.ply")
    exported = GaussianModel.from_splats(splats)
    with torch.no_grad():
        again = rasterize(camera, **exported.render_inputs(), background=torch.zeros(3), settings=RENDER).rgb
    assert run.amax() > 0.3  # the person is in the picture
    assert (again - run).abs().max() < 1e-5  # 3.6e-7 measured (float32); 0.67 without rotating the SH


def test_frames_concatenate_the_background_and_pad_sh():
    background = GaussianModel.from_points(torch.zeros(2, 3), torch.full((2, 3), 0.5), torch.full((2,), 0.1), 0.5, 0)
    person_like = GaussianModel.from_points(torch.ones(3, 3), torch.full((3, 3), 0.2), torch.full((3,), 0.1), 0.5, 2)
    both = concatenate([background.to_splats(), person_like.to_splats()])
    assert len(both) == 5 and both.sh_degree == 2 and not both.sh[:2, 1:].any()
    assert with_sh_degree(both, 3).sh_degree == 3 and np.array_equal(with_sh_degree(both, 3).sh[:, :9], both.sh)
    assert np.array_equal(with_sh_degree(both, 0).sh, both.sh[:, :1])
    with pytest.raises(ValueError, match="nothing to export"):
        frame_splats(None, [], 0)
