"""The ``render`` settings travel whole: every render path (training, scoring, turntables, holes, speed
timings) hands the very settings it was given to the rasterizer, so with ``render.antialiased: true`` they
all draw antialiased, and the turntable's picture is the rasterizer's own picture under those settings."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from glimpse.body.config import BodyConfig, resolve_model_path
from glimpse.body.model import BodyModel
from glimpse.body.motion import builtin_motion
from glimpse.body.params import BodyParams
from glimpse.cameras.model import render_camera
from glimpse.cameras.orbit import box_centre, turn_cameras
from glimpse.config import config_from_mapping, load_pipeline_yaml
from glimpse.eval import coverage, renders, speed
from glimpse.eval.config import SpeedConfig
from glimpse.humans import compose
from glimpse.humans.person import initial_person
from glimpse.io.images import rgb_to_uint8
from glimpse.render import RenderConfig, rasterize

PIPELINE = load_pipeline_yaml()
BODY = config_from_mapping(BodyConfig, PIPELINE["body"], "body")
CPU = torch.device("cpu")
ANTIALIASED = RenderConfig(backend="auto", sh_degree=1, antialiased=True)
CLASSIC = RenderConfig(backend="auto", sh_degree=1, antialiased=False)
TURNTABLE = dict(frames=2, size=48, radius_m=2.6, fovy_deg=49.1)


@pytest.fixture(scope="module")
def body_model() -> BodyModel:
    return BodyModel.from_file(resolve_model_path(BODY))


@pytest.fixture(scope="module")
def person(body_model):
    standing = BodyParams(np.array([0, 1]), np.zeros(10), np.zeros((2, 3)), np.zeros((2, 69)), np.zeros((2, 3)), 1.0,
                          "free", np.zeros(2, bool))
    return initial_person("p0", body_model, standing, BODY.canonical_hip_angle_deg, BODY.skinning, 0.5, 0.9, 3, 1)


@pytest.fixture
def seen_settings(monkeypatch) -> list[RenderConfig]:
    """Every ``settings`` the render paths under test hand to the rasterizer, in call order."""
    seen: list[RenderConfig] = []

    def spy(*args, settings: RenderConfig, **kwargs):
        seen.append(settings)
        return rasterize(*args, settings=settings, **kwargs)

    for module in (coverage, renders, speed, compose):
        monkeypatch.setattr(module, "rasterize", spy)
    return seen


def test_every_render_path_hands_its_settings_to_the_rasterizer_whole(person, body_model, seen_settings):
    list(renders.canonical_turntable(person, render=ANTIALIASED, device=CPU, **TURNTABLE))
    coverage.canonical_hole_share(person, body_model.faces.numpy(), coverage.CoverageConfig(views=2, size_px=32),
                                  ANTIALIASED, CPU)
    timing = config_from_mapping(SpeedConfig, dict(PIPELINE["07_eval"]["speed"], frames=1, warmup_frames=0), "speed")
    speed.time_novel_pose(person, builtin_motion("walk", 2, 30.0), 32, timing, ANTIALIASED, CPU)
    camera = render_camera(turn_cameras(box_centre(person.rig.canonical_vertices.numpy())[None], 2.6, 49.1, 32)[0], CPU)
    with torch.no_grad():
        compose.render_frame(camera, compose.frame_gaussians(camera, 0, [person], 1), 1, ANTIALIASED)
    assert len(seen_settings) == TURNTABLE["frames"] + 2 + 1 + 1
    assert all(settings is ANTIALIASED for settings in seen_settings)


def test_the_turntable_draws_what_the_rasterizer_draws_under_the_same_settings(person):
    for settings in (ANTIALIASED, CLASSIC):
        frames = list(renders.canonical_turntable(person, render=settings, device=CPU, **TURNTABLE))
        centre = box_centre(person.rig.canonical_vertices.numpy())
        pinhole = turn_cameras(np.tile(centre, (TURNTABLE["frames"], 1)), TURNTABLE["radius_m"],
                               TURNTABLE["fovy_deg"], TURNTABLE["size"])[1]
        with torch.no_grad():
            direct = rasterize(render_camera(pinhole, CPU),
                               **person.model.render_inputs(settings.sh_degree), background=torch.ones(3),
                               settings=settings).rgb
        assert np.array_equal(frames[1], rgb_to_uint8(direct))
    antialiased = np.stack(list(renders.canonical_turntable(person, render=ANTIALIASED, device=CPU, **TURNTABLE)))
    classic = np.stack(list(renders.canonical_turntable(person, render=CLASSIC, device=CPU, **TURNTABLE)))
    assert np.abs(antialiased.astype(int) - classic).max() > 0  # the setting changes the picture
