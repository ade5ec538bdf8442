"""Rendering finished runs fast: a frozen person's posing (the C++ kernel and the cached PyTorch path)
against the training path, and the render-speed measurement (glimpse/eval/speed.py): the memory
probe, the novel-pose set-up it times, what it reports (stage 07's speed.json: tests/test_joint.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from glimpse.body.config import BodyConfig, resolve_model_path
from glimpse.body.model import BodyModel
from glimpse.body.motion import builtin_motion
from glimpse.body.params import BodyParams
from glimpse.cameras.model import render_camera
from glimpse.cameras.orbit import orbit_camera
from glimpse.config import config_from_mapping, load_pipeline_yaml
from glimpse.errors import ConfigError
from glimpse.eval.config import SpeedConfig
from glimpse.eval.speed import PeakMemory, driven_in_body_frame, evenly_spread, time_novel_pose
from glimpse.humans.person import initial_person
from glimpse.render import RenderConfig, rasterize

PIPELINE = load_pipeline_yaml()
BODY = config_from_mapping(BodyConfig, PIPELINE["body"], "body")
SPEED = config_from_mapping(SpeedConfig, PIPELINE["07_eval"]["speed"], "07_eval.speed")
CPU = torch.device("cpu")


@pytest.fixture(scope="module")
def person():
    body_model = BodyModel.from_file(resolve_model_path(BODY))
    standing = BodyParams(np.array([0]), np.zeros(10), np.zeros((1, 3)), np.zeros((1, 69)), np.zeros((1, 3)), 1.0,
                          "free", np.zeros(1, bool))
    return initial_person("p0", body_model, standing, BODY.canonical_hip_angle_deg, BODY.skinning, 0.5, 0.9, 3, 2)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_a_frozen_person_poses_as_the_training_path_does(degree, monkeypatch):
    from glimpse.humans.person import PersonGaussians
    from glimpse.render import composite_cpu

    body_model = BodyModel.from_file(resolve_model_path(BODY))
    rng = np.random.default_rng(degree)
    frames = 2
    body = BodyParams(np.arange(frames), rng.normal(0, 0.5, 10), rng.normal(0, 0.4, (frames, 3)),
                      rng.normal(0, 0.3, (frames, 69)), rng.normal(0, 1.0, (frames, 3)), 1.3, "free",
                      np.zeros(frames, bool))
    start = initial_person("p0", body_model, body, BODY.canonical_hip_angle_deg, BODY.skinning, 0.5, 0.9, 3, 3)
    with torch.no_grad():  # anisotropic, turned, coloured from every direction
        start.model.sh_rest.normal_(0.0, 0.2, generator=torch.Generator().manual_seed(degree))
        start.model.quats.copy_(torch.as_tensor(rng.normal(size=(len(start.model), 4))))
        start.model.log_scales.add_(torch.as_tensor(rng.normal(0.0, 0.5, (len(start.model), 3)), dtype=torch.float32))
    centre = torch.tensor([0.3, -0.2, 4.0])
    expected = start.posed(1, centre, degree)  # gradients on: the training path
    frozen = PersonGaussians(start.pid, start.model, start.grid, start.rig, body).freeze()
    with torch.no_grad():
        kernel = frozen.posed(1, centre, degree)
        monkeypatch.setattr(composite_cpu, "available", lambda: False)  # PyTorch only, both paths
        cached = frozen.posed(1, centre, degree)
    expected_torch = start.posed(1, centre, degree)
    for name in ("means", "covariances", "opacities", "colors"):
        want = getattr(expected, name).detach()
        assert torch.allclose(getattr(kernel, name), want, rtol=1e-5, atol=2e-6), name
        want = getattr(expected_torch, name).detach()
        assert torch.allclose(getattr(cached, name), want, rtol=1e-6, atol=1e-7), name


def test_the_memory_probe_sees_a_temporary_allocation():
    with PeakMemory(CPU) as peak:
        block = torch.ones(16 * 2**20)  # 64 MB, touched
        block += 1.0
        del block
    if peak.extra_mb is None:
        pytest.skip("this system cannot reset its peak resident memory (/proc/self/clear_refs)")
    assert 56 < peak.extra_mb < 200
    with PeakMemory(CPU) as quiet:
        torch.ones(16)
    assert quiet.extra_mb < 16


def test_the_driven_person_walks_at_the_pelvis_the_camera_circles(person):
    motion = builtin_motion("walk", 8, 30.0)
    driven = driven_in_body_frame(person, motion)
    pelvis = driven.rig.rest_joints[0] + driven.transl  # [T, 3]
    for step in (0, 7):
        posed = driven.posed(step, torch.zeros(3), 0)
        assert torch.linalg.norm(posed.means.mean(0) - pelvis[step]) < 0.2  # the body is around its pelvis
    assert torch.linalg.norm(pelvis[7] - pelvis[0]) > 0.05  # the walk moves forward
    size = 96
    camera = render_camera(orbit_camera(pelvis[3].double().numpy(), 90.0, 0.0, SPEED.radius_m, SPEED.fovy_deg, size), CPU)
    posed = driven.posed(3, camera.centre, 0)
    alpha = rasterize(camera, means=posed.means, covariances=posed.covariances, opacities=posed.opacities,
                      colors=posed.colors, settings=RenderConfig("auto", 0, antialiased=False)).alpha
    rows = torch.nonzero(alpha.amax(dim=1) > 0.5)[:, 0]
    height = (rows.max() - rows.min() + 1) / size
    assert 0.55 < height < 0.85  # as the protocol says: the body fills about 70% of the image height


def test_a_timing_counts_the_persons_gaussians_and_its_parts(person):
    config = dataclasses.replace(SPEED, frames=3, warmup_frames=1)
    timing = time_novel_pose(person, builtin_motion("walk", 3, 30.0), 48, config, RenderConfig("cpu", 2, antialiased=False), CPU)
    assert timing.gaussians == len(person.model) and (timing.width, timing.height, timing.frames) == (48, 48, 3)
    assert timing.posing_ms > 0 and timing.raster_ms > 0 and timing.fps == pytest.approx(1000 / timing.ms_per_frame)
    assert timing.as_dict()["fps"] == pytest.approx(timing.fps, abs=0.01)


def test_speed_settings_are_checked_and_frames_spread():
    with pytest.raises(ConfigError, match="07_eval.speed"):
        dataclasses.replace(SPEED, sizes_px=[])
    with pytest.raises(ConfigError, match="07_eval.speed"):
        dataclasses.replace(SPEED, fovy_deg=180.0)
    assert evenly_spread([3, 4, 5, 6, 7], 3) == [3, 5, 7] and evenly_spread([1, 2], 5) == [1, 2]
