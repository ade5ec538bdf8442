"""Stage 04: the never-seen machinery against independent references, then the stage on fixture
scenes: the textured sphere of a static camera, SfM points of a moving one, quality against the
place rendered without people by the mesh renderer (no ghosts, never-seen regions found), resume
after a kill, and clear errors."""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import torch

from glimpse.background.evaluate import SeenTest, backproject, seen_weights
from glimpse.background.train import TrainingView
from glimpse.background.truth import judge_background
from glimpse.errors import GlimpseError
from glimpse.fixtures.scenes import make_scene
from glimpse.gaussians.model import GaussianModel
from glimpse.gaussians.ply import read_gaussians_ply
from glimpse.io.video import read_mp4
from glimpse.render import Camera, rasterize
from glimpse.render.config import RenderConfig
from tests.stage_helpers import REPO, read_json, run

UPSTREAM = ("01_sfm", "02_smpl_fit", "03_masks")
RENDER = RenderConfig(backend="auto", sh_degree=0, antialiased=False)


def _camera(width: int = 32, height: int = 24) -> Camera:
    K = torch.tensor([[30.0, 0, (width - 1) / 2], [0, 30.0, (height - 1) / 2], [0, 0, 1]])
    return Camera(K, torch.eye(3), torch.zeros(3), width, height)


def test_seen_weights_are_each_gaussians_blending_weight_over_background_pixels():
    """The gradient trick against the forward pass: a one-hot colour renders a Gaussian's weights."""
    g = torch.Generator().manual_seed(0)
    n = 6
    model = GaussianModel.from_points(torch.randn(n, 3, generator=g) * 0.3 + torch.tensor([0, 0, 3.0]),
                                      torch.rand(n, 3, generator=g), torch.full((n,), 0.2), 0.6, sh_degree=0)
    background = torch.zeros(24, 32, dtype=torch.bool)
    background[:, :20] = True
    view = TrainingView(0, _camera(), lambda _: (torch.zeros(24, 32, 3, dtype=torch.uint8), background))
    weights = seen_weights(model, [view, view], RENDER)
    inputs = {k: v.detach() for k, v in model.render_inputs().items() if k not in ("sh", "sh_degree")}
    for i in range(n):
        onehot = torch.zeros(n, 3)
        onehot[i, 0] = 1.0
        rendered = rasterize(view.camera, **inputs, colors=onehot, settings=RENDER).rgb[..., 0]
        assert weights[i] == pytest.approx(2 * float(rendered[background].sum()), rel=1e-4, abs=1e-6)


def test_backprojected_pixels_land_on_themselves_and_are_seen_where_the_background_is():
    camera = _camera()
    depth = torch.full((24, 32), 2.0) + torch.linspace(0, 1, 32)
    points = backproject(camera, depth)
    cam = points @ camera.R.T + camera.t
    uv = cam[:, :2] / cam[:, 2:] * 30.0 + torch.tensor([15.5, 11.5])
    v, u = torch.meshgrid(torch.arange(24.0), torch.arange(32.0), indexing="ij")
    assert torch.allclose(uv, torch.stack([u, v], -1).reshape(-1, 2), atol=1e-4)
    first = torch.zeros(24, 32, dtype=torch.bool)
    first[:, :10] = True
    second = torch.zeros(24, 32, dtype=torch.bool)
    second[:, 20:] = True
    pixels = {k: (torch.zeros(24, 32, 3, dtype=torch.uint8), bg) for k, bg in enumerate((first, second))}
    views = [TrainingView(k, camera, pixels.__getitem__) for k in pixels]
    seen = SeenTest(views).seen(points).reshape(24, 32)
    assert len(SeenTest(views).cameras) == 1  # one camera: the two frames' masks are merged
    assert torch.equal(seen, first | second)
    behind = points - torch.tensor([0.0, 0.0, 10.0])  # behind the camera: never seen
    assert not SeenTest(views).seen(behind).any()
SHORT = "04_bg_pretrain.schedule_scale=0.02"  # 600 iterations: enough on these small scenes


def _upstream(name: str, size: str, root, seed: int = 0):
    scene = make_scene(name, root / "scene", size, seed=seed)
    for stage in UPSTREAM:
        run(stage, scene, root / "out")
    return scene, root / "out" / f"{name}_{size}"


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    root = tmp_path_factory.mktemp("bg_demo")
    scene, run_dir = _upstream("demo", "small", root)
    return scene, run_dir, run("04_bg_pretrain", scene, root / "out", SHORT)


def test_static_camera_starts_from_a_sphere_around_the_people(demo):
    scene, run_dir, out = demo
    init = read_json(out / "init.json")
    assert init["format"] == "glimpse-bg-init/1" and init["kind"] == "sphere" and init["radius"] == 30.0
    truth = [np.load(scene.with_name("scene.groundtruth") / f"{pid}_body.npz")["transl"] for pid in ("p0", "p1")]
    assert np.linalg.norm(np.array(init["centre"]) - np.concatenate(truth).mean(0)) < 0.3  # fitted, not exact
    splats, metadata = read_gaussians_ply(out / "background.ply")
    assert metadata["stage"] == "04_bg_pretrain" and len(splats) == read_json(out / "report.json")["gaussians"]
    assert splats.sh_degree == 2
    manifest = read_json(out / "manifest.json")
    assert manifest["summary"]["iterations"] == 600 and manifest["summary"]["iterations_per_s"] > 0
    video = read_mp4(out / "renders" / "background.mp4")
    assert video.shape[0] == len(read_json(run_dir / "01_sfm" / "cameras.json")["frames"])
    assert not (run_dir / ".work" / "04_bg_pretrain").exists()


def test_background_matches_the_empty_place_and_has_no_ghosts(demo):
    scene, run_dir, out = demo
    report = read_json(out / "report.json")
    assert report["psnr_background_db"] > 28.0  # against the input frames, on the pixels trained on
    judged = judge_background(out, run_dir / "01_sfm", scene, static_camera=True)
    # Against the place rendered without people by the mesh renderer:
    assert judged["psnr_visible_db"] > 27.0
    # Behind people (seen in other frames): close to the visible pixels, far above a baked-in person.
    assert judged["psnr_behind_people_db"] > judged["psnr_visible_db"] - 4.0
    assert judged["psnr_behind_people_db"] > judged["psnr_frame_behind_people_db"] + 10.0


def test_never_seen_regions_of_a_person_who_stays_put(tmp_path):
    scene, run_dir = _upstream("lower_body_occluded", "small", tmp_path)
    out = run("04_bg_pretrain", scene, tmp_path / "out", SHORT)
    judged = judge_background(out, run_dir / "01_sfm", scene, static_camera=True)
    assert judged["never_seen_truth_fraction"] > 0.01
    assert judged["never_seen_recall"] > 0.95  # every truly hidden pixel is reported
    assert judged["never_seen_reported_fraction"] < 4 * judged["never_seen_truth_fraction"]  # grown masks, no more
    report = read_json(out / "report.json")
    assert report["gaussians_never_seen"] > 0 and report["never_seen_in_every_frame_fraction"] > 0.01


def test_moving_camera_starts_from_the_sfm_points(tmp_path):
    scene, run_dir = _upstream("moving_camera", "small", tmp_path)
    out = run("04_bg_pretrain", scene, tmp_path / "out", "04_bg_pretrain.schedule_scale=0.05")  # a sparse start
    init = read_json(out / "init.json")
    assert init["kind"] == "points" and init["initial_gaussians"] == init["points"] > 100
    judged = judge_background(out, run_dir / "01_sfm", scene, static_camera=False)
    assert judged["psnr_visible_db"] > 24.0
    assert judged["psnr_behind_people_db"] > judged["psnr_frame_behind_people_db"] + 6.0


def test_a_killed_run_resumes_from_its_checkpoint_and_ends_as_an_uninterrupted_one(tmp_path):
    """... and as one that keeps two frames in memory instead of every frame."""
    scene, run_dir = _upstream("demo", "tiny", tmp_path)
    twin = tmp_path / "twin"  # the same upstream outputs under a second root, for an uninterrupted run
    for stage in UPSTREAM:
        shutil.copytree(run_dir / stage, twin / "demo_tiny" / stage)
    params = "04_bg_pretrain.schedule_scale=0.01 04_bg_pretrain.checkpoint_every=50 04_bg_pretrain.render_video=false"
    checkpoint = run_dir / ".work" / "04_bg_pretrain" / "checkpoint.pt"
    process = subprocess.Popen([sys.executable, str(REPO / "stages" / "04_bg_pretrain" / "run.py"), "--scene",
                                str(scene), "--out", str(tmp_path / "out"), "--params", params],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    while not checkpoint.is_file() and process.poll() is None and time.time() < deadline:
        time.sleep(0.02)
    process.send_signal(signal.SIGKILL)
    process.wait()
    assert checkpoint.is_file() and not (run_dir / "04_bg_pretrain").exists()
    out = run("04_bg_pretrain", scene, tmp_path / "out", params)
    report = read_json(out / "report.json")
    assert report["resumed_from_iteration"] >= 50 and report["resumed_from_iteration"] % 50 == 0
    assert not checkpoint.exists()
    again = run("04_bg_pretrain", scene, twin, params + " compute.frame_cache=2 compute.frame_read_ahead=1")
    assert read_json(again / "report.json")["resumed_from_iteration"] == 0  # and its frames read two at a time
    assert (again / "background.ply").read_bytes() == (out / "background.ply").read_bytes()


def test_a_checkpoint_of_other_parameters_is_not_resumed(tmp_path):
    scene, run_dir = _upstream("demo", "tiny", tmp_path)
    params = "04_bg_pretrain.schedule_scale=0.01 04_bg_pretrain.render_video=false"
    first = run("04_bg_pretrain", scene, tmp_path / "out", params)
    ply = (first / "background.ply").read_bytes()
    work = run_dir / ".work" / "04_bg_pretrain"
    work.mkdir(parents=True)
    from glimpse.io.checkpoint import save_checkpoint

    save_checkpoint(work / "checkpoint.pt", "another configuration", {"step": 10})
    again = run("04_bg_pretrain", scene, tmp_path / "out", params)
    assert read_json(again / "report.json")["resumed_from_iteration"] == 0
    assert (again / "background.ply").read_bytes() == ply  # deterministic


def test_clear_errors(tmp_path):
    scene, _ = _upstream("demo", "tiny", tmp_path)
    with pytest.raises(GlimpseError, match="init=points needs stage 01's points.ply"):
        run("04_bg_pretrain", scene, tmp_path / "out", "04_bg_pretrain.init=points")
    with pytest.raises(GlimpseError, match="outside the background sphere.*sphere_radius_m"):
        run("04_bg_pretrain", scene, tmp_path / "out", "04_bg_pretrain.sphere_radius_m=1.0")
