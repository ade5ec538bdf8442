"""Stage 06 (joint optimisation) and stage 07 (metrics): posing against the body model, the polar
rotation against SVD, the schedule, the occluder exclusion, resume, and the stages on the tiny demo
(quality against the untrained bodies, rendered against the mesh renderer's ground truth)."""

from __future__ import annotations

import io
import math
import time
from dataclasses import replace

import numpy as np
import pytest
import torch
from PIL import Image

from glimpse.body.config import BodyConfig, resolve_model_path
from glimpse.body.lbs import batch_rodrigues
from glimpse.body.model import BodyModel
from glimpse.body.models import BodyModels
from glimpse.body.params import BodyParams, read_body_params
from glimpse.cameras.model import PinholeCamera, render_camera
from glimpse.config import config_from_mapping, load_pipeline_yaml
from glimpse.errors import EXIT_BAD_INPUT, ConfigError, GlimpseError
from glimpse.eval.never_seen import PosedBodies
from glimpse.eval.score import EMPTY_ROW, FLAT_ROW, RENDER_ROW, person_flat_row, score_views
from glimpse.eval.views import ViewSet, heldout_views
from glimpse.fixtures.scenes import make_scene
from glimpse.gaussians.model import GaussianModel
from glimpse.gaussians.ply import read_gaussians_ply
from glimpse.humans.load import load_trained_people
from glimpse.humans.person import initial_person, joint_transforms, polar_rotation
from glimpse.humans.visibility import BodyVisibility, body_visibility
from glimpse.io.cameras_json import read_cameras_json
from glimpse.joint.config import JointConfig
from glimpse.joint.stage import static_occlusion
from glimpse.joint.train import people_box, reconstruction_terms
from glimpse.metrics.lpips import LPIPS
from glimpse.prior import PriorContext, check_prior_kind, make_prior, resolve_prior_kind
from glimpse.prior.config import SurfacePriorConfig
from glimpse.render.config import RenderConfig
from glimpse.render.projection import ALPHA_MIN
from glimpse.scene import load_scene
from tests.stage_helpers import read_json, run

PIPELINE = load_pipeline_yaml()
BODY = config_from_mapping(BodyConfig, PIPELINE["body"], "body")
JOINT = config_from_mapping(JointConfig, PIPELINE["06_joint_opt"], "06_joint_opt")
SURFACE = config_from_mapping(SurfacePriorConfig, PIPELINE["prior_surface"], "prior_surface")
RENDER = RenderConfig(backend="auto", sh_degree=2, antialiased=False)


@pytest.fixture(scope="module")
def body_model() -> BodyModel:
    return BodyModel.from_file(resolve_model_path(BODY))


def _body(frames: int, seed: int = 0) -> BodyParams:
    rng = np.random.default_rng(seed)
    return BodyParams(np.arange(frames), rng.normal(0, 0.5, 10), rng.normal(0, 0.4, (frames, 3)),
                      rng.normal(0, 0.2, (frames, 69)), rng.normal(0, 1.0, (frames, 3)), 1.3, "free",
                      np.zeros(frames, bool))


def test_joint_transforms_are_the_body_models(body_model):
    body = _body(2)
    person = initial_person("p0", body_model, body, 30.0, BODY.skinning, 0.5, 0.9, 3, 0)
    for row in range(2):
        expected = body_model(body.betas, body.global_orient[row:row + 1], body.body_pose[row:row + 1],
                              body.transl[row:row + 1], body.scale).transforms[0]
        pose = torch.as_tensor(np.concatenate([body.global_orient[row], body.body_pose[row]]), dtype=torch.float32)
        found = joint_transforms(person.rig, pose, torch.as_tensor(body.transl[row], dtype=torch.float32), body.scale)
        torch.testing.assert_close(found, expected.float(), rtol=1e-4, atol=1e-4)


def test_gaussians_on_the_canonical_body_follow_the_posed_body(body_model):
    """Gaussians initialised on the Da-pose vertices land on the body model's posed vertices (up to the
    pose blend shapes, which Gaussians do not get, and the grid's interpolation)."""
    body = _body(1, seed=1)
    person = initial_person("p0", body_model, body, 30.0, BODY.skinning, 0.5, 0.9, 3, 0)
    posed = person.posed(0, torch.tensor([0.0, 0.0, -5.0]), 0)
    expected = body_model(body.betas, body.global_orient, body.body_pose, body.transl, body.scale).vertices[0].float()
    error = (posed.means.detach() - expected).norm(dim=1) / body.scale
    assert float(error.mean()) < 0.01 and float(error.quantile(0.99)) < 0.04  # metres of body
    assert torch.allclose(posed.opacities, torch.full_like(posed.opacities, 0.9))
    assert torch.allclose(posed.colors, torch.full_like(posed.colors, 0.5), atol=1e-6)


def test_polar_rotation_matches_svd_on_blends_of_bone_rotations():
    g = torch.Generator().manual_seed(0)
    first = batch_rodrigues(torch.randn(500, 3, generator=g))
    second = first @ batch_rodrigues(0.6 * torch.randn(500, 3, generator=g))
    weights = torch.rand(500, 1, 1, generator=g)
    blended = (weights * first + (1 - weights) * second) * 1.7
    u, _, vh = torch.linalg.svd(blended)
    torch.testing.assert_close(polar_rotation(blended), u @ vh, rtol=0, atol=1e-5)


def test_schedule_is_the_papers_scaled():
    config = replace(JOINT, schedule_scale=0.1)
    assert config.total_iterations == 1200
    assert config.people_strategy().densify_steps == {200, 250, 300}
    assert config.centres_fixed_at(150) and not config.centres_fixed_at(151)
    assert [s for s in range(1, 400) if config.people_strategy().prunes_at(s)] == [200, 250, 300, 350]
    assert [config.human_sh_degree(s, 2) for s in (1, 200, 201, 401, 1000)] == [0, 0, 1, 2, 2]
    assert replace(JOINT, schedule_scale=1.0).people_strategy().densify_steps == {2000, 2500, 3000}


def test_occluded_pixels_give_no_gradient_and_people_are_not_excluded():
    union = np.zeros((8, 8), bool)
    union[2:5, 2:5] = True  # a person in front of another
    occluder_a = np.zeros((8, 8), bool)
    occluder_a[3:7, 3:7] = True  # hidden partly by that person, partly by a table
    hidden = static_occlusion(union, [occluder_a])
    assert hidden[6, 6] and not hidden[3, 3]
    rendered = torch.rand(40, 40, 3, requires_grad=True)
    target = torch.rand(40, 40, 3)
    keep = torch.ones(40, 40, dtype=torch.bool)
    keep[10:20, 10:20] = False
    config = replace(JOINT, loss=replace(JOINT.loss, lpips=0.0))
    terms = reconstruction_terms(config, None, rendered, target, keep, None)
    sum(terms.values()).backward()
    assert rendered.grad[10:20, 10:20].abs().max() == 0 and rendered.grad[keep].abs().max() > 0


def test_people_box_grows_to_the_minimum_size_inside_the_image():
    union = np.zeros((50, 60), bool)
    union[0:3, 58:60] = True
    y0, y1, x0, x1 = people_box(union, 2, 32)
    assert (y1 - y0, x1 - x0) == (32, 32) and y0 == 0 and x1 == 60
    assert people_box(np.zeros((5, 5), bool), 2, 32) is None


def test_priors_are_chosen_by_name_and_unknown_ones_are_listed():
    assert resolve_prior_kind("auto") == "surface" and check_prior_kind("none") == "none"
    assert resolve_prior_kind("auto", diffusion_ready=True) == "sds" and check_prior_kind("sds") == "sds"
    with pytest.raises(ConfigError, match="registered priors: none, surface, sds"):
        check_prior_kind("magic")


# --- the stages on the tiny demo ------------------------------------------------------------------------

SHORT = ("04_bg_pretrain.schedule_scale=0.01 06_joint_opt.schedule_scale=0.02 "  # 300 and 240 iterations
         "07_eval.renders.orbit_frames=6 07_eval.renders.turntable_frames=4 07_eval.renders.turntable_size_px=48 "
         "07_eval.renders.motion_seconds=2 07_eval.renders.time=1 "  # short videos, from frame 1 (p0 in view)
         "07_eval.speed.sizes_px=[64] 07_eval.speed.frames=2 07_eval.speed.warmup_frames=1 "
         "07_eval.speed.scene_frames=2")


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    root = tmp_path_factory.mktemp("joint")
    scene = make_scene("demo", root / "scene", "tiny", seed=0)
    for stage in ("01_sfm", "02_smpl_fit", "03_masks", "04_bg_pretrain", "05_textual_inversion", "06_joint_opt",
                  "07_eval"):
        run(stage, scene, root / "out", SHORT)
    return scene, root / "out" / "demo_tiny"


def test_stage06_writes_canonical_people_and_keeps_the_backgrounds_count(tiny):
    scene, run_dir = tiny
    out = run_dir / "06_joint_opt"
    report = read_json(out / "report.json")
    assert report["prior"] == "surface" and report["iterations"] == 240  # auto: the offline prior
    assert {"loss_prior_colour", "loss_prior_silhouette"} <= set(report["loss_history"][-1])
    before, _ = read_gaussians_ply(run_dir / "04_bg_pretrain" / "background.ply")
    after, metadata = read_gaussians_ply(out / "background.ply")
    assert len(after.means) == len(before.means) and metadata["stage"] == "06_joint_opt"
    for pid in ("p0", "p1"):
        splats, meta = read_gaussians_ply(out / "humans" / pid / "canonical.ply")
        assert meta["frame"] == "canonical" and len(splats.means) == report["people"][pid]["gaussians"]
        body = read_body_params(out / "humans" / pid / "body.npz")
        fitted = read_body_params(run_dir / "02_smpl_fit" / "humans" / pid / "body.npz")
        assert np.abs(body.body_pose - fitted.select(body.frame_ids).body_pose).max() > 0  # poses refined
        assert np.abs(body.body_pose - fitted.select(body.frame_ids).body_pose).max() < 0.2
        seen = BodyVisibility.read(out / "humans" / pid / "visibility.npz").seen.mean()  # one camera: a side
        assert 0.2 < seen < 0.8 and report["people"][pid]["body_vertices_seen"] == pytest.approx(seen, abs=1e-4)
    losses = report["loss_history"]
    assert np.mean([e["total"] for e in losses[-3:]]) < losses[0]["total"]
    assert (out / "renders" / "joint.mp4").stat().st_size > 0


def test_training_beats_the_untrained_bodies_on_held_out_views(tiny, body_model):
    """Humans-only PSNR on the held-out cameras (mesh-rendered ground truth) against the same bodies grey."""
    scene, run_dir = tiny
    trained = read_json(run_dir / "07_eval" / "metrics.json")["tables"]["humans"]["rows"][0]
    people = load_trained_people(run_dir / "06_joint_opt" / "humans", BodyModels(body_model))
    grey = [initial_person(p.pid, body_model, p.body, 30.0, BODY.skinning, 0.5, 0.9, 3, 0) for p in people]
    views = heldout_views(load_scene(scene), True)
    background = GaussianModel.from_splats(read_gaussians_ply(run_dir / "06_joint_opt" / "background.ply")[0])
    visibility = {p.pid: BodyVisibility.read(run_dir / "06_joint_opt" / "humans" / p.pid / "visibility.npz")
                  for p in people}
    baseline = score_views(ViewSet("held-out", "test", views), grey, background, RENDER, LPIPS("alex"),
                           torch.device("cpu"), PosedBodies(grey, visibility, BodyModels(body_model)),
                           [np.full(3, 0.5)] * len(grey)).rows["humans"][0]
    assert trained["psnr"] > baseline.psnr + 1.0


def test_stage07_writes_the_standard_videos(tiny):
    from glimpse.io.video import read_mp4

    scene, run_dir = tiny
    renders = run_dir / "07_eval" / "renders"
    manifest = read_json(run_dir / "07_eval" / "manifest.json")
    frames = sorted(read_cameras_json(run_dir / "01_sfm" / "cameras.json")[2])
    fps = load_scene(scene).fps
    expected = {"input.mp4": len(frames), "orbit.mp4": len(frames), "freeze.mp4": 6, "person_p0.mp4": 4,
                "person_p1.mp4": 4, "removed_p0.mp4": len(frames), "motion_p0.mp4": round(2 * fps)}
    expected.update({f"heldout_{name}.mp4": len(cam.images) for name, cam in load_scene(scene).eval_cameras.items()})
    assert set(manifest["summary"]["renders"]) == set(expected)
    for name, count in expected.items():
        video = read_mp4(renders / name)
        assert len(video) == count, name
    width = read_cameras_json(run_dir / "01_sfm" / "cameras.json")[0]
    assert read_mp4(renders / "input.mp4").shape[2] >= 2 * width  # render beside the input frame
    assert read_mp4(renders / "removed_p0.mp4").shape[2] == 2 * width  # beside it, the never-seen pixels tinted
    moved = read_mp4(renders / "motion_p0.mp4").astype(int)
    assert np.abs(moved[-1] - moved[0]).max() > 50  # the driven person walked


def test_stage07_times_each_person_in_novel_poses_and_the_whole_scene(tiny):
    from glimpse.eval.speed import SPEED_FORMAT

    _, run_dir = tiny
    speed = read_json(run_dir / "07_eval" / "speed.json")
    people = read_json(run_dir / "06_joint_opt" / "report.json")["people"]
    assert speed["format"] == SPEED_FORMAT and speed["backend"] == "cpu" and set(speed["people"]) == {"p0", "p1"}
    for pid, entry in speed["people"].items():
        timing = entry["novel_pose"]["64"]
        assert entry["gaussians"] == timing["gaussians"] == people[pid]["gaussians"]
        assert (timing["width"], timing["height"], timing["frames"]) == (64, 64, 2) and timing["fps"] > 0
    background, _ = read_gaussians_ply(run_dir / "06_joint_opt" / "background.ply")
    scene = speed["scene"]
    assert len(background.means) < scene["gaussians"] <= len(background.means) + sum(
        e["gaussians"] for e in speed["people"].values())
    assert scene["frames"] == 2 and (scene["peak_extra_mb"] is None or scene["peak_extra_mb"] >= 0)
    table = (run_dir / "07_eval" / "speed.md").read_text()
    assert "| p0 |" in table and "| input views |" in table and "Protocol:" in table


REPORT_LOADS = """async () => {
  const images = [...document.images].map(i => ({src: i.getAttribute("src"), width: i.naturalWidth}));
  const videos = await Promise.all([...document.querySelectorAll("video")].map(v => new Promise(done => {
    const report = () => done({src: v.getAttribute("src"), ready: v.readyState, width: v.videoWidth,
                               error: v.error ? v.error.code : null});
    if (v.readyState >= 2) return report();
    v.addEventListener("loadeddata", report); v.addEventListener("error", report); setTimeout(report, 10000);
    v.preload = "auto"; v.load();
  })));
  return {images, videos};
}"""


def test_stage07_writes_a_report_whose_every_image_and_video_loads_in_a_browser(tiny):
    from playwright.sync_api import sync_playwright

    from tests.support.browser import launch

    _, run_dir = tiny
    page_path = run_dir / "report.html"
    text = page_path.read_text()
    for anchor in ("scene", "metrics", "views", "training", "bodies", "masks", "videos", "parameters", "timings",
                   "logs"):
        assert f'<section id="{anchor}">' in text
    humans = read_json(run_dir / "07_eval" / "manifest.json")["summary"]["humans_psnr_db"]
    assert f"PSNR {humans:.2f} dB" in text  # the headline is stage 07's
    assert "06_joint_opt.schedule_scale" in text and "not run" not in text  # SHORT's overrides; every stage ran
    assert "Seen and never-seen regions of the people" in text  # the two tables side by side
    with sync_playwright() as playwright:
        browser = launch(playwright)
        page = browser.new_page()
        failed: list[str] = []
        page.on("requestfailed", lambda request: failed.append(request.url))
        page.goto(page_path.as_uri())
        page.wait_for_load_state("load")
        loaded = page.evaluate(REPORT_LOADS)
        browser.close()
    assert failed == []
    pictures = {image["src"] for image in loaded["images"]}
    assert pictures == {f"report_files/{p.name}" for p in (run_dir / "report_files").glob("*.png")}
    assert {"report_files/loss_joint.png", "report_files/gaussians.png", "report_files/input_psnr.png",
            "report_files/timings.png"} <= pictures
    assert all(image["width"] > 0 for image in loaded["images"]), loaded["images"]
    videos = {video["src"] for video in loaded["videos"]}
    assert {f"07_eval/renders/{name}" for name in read_json(run_dir / "07_eval" / "manifest.json")["summary"]
            ["renders"]} | {"02_smpl_fit/overlay.mp4", "06_joint_opt/renders/joint.mp4"} <= videos
    assert all(v["ready"] >= 2 and v["width"] > 0 and v["error"] is None for v in loaded["videos"]), loaded["videos"]


def view_config(**changes):
    from glimpse.view.config import ViewConfig

    config = config_from_mapping(ViewConfig, load_pipeline_yaml(resolve_auto=False)["view"], "view")
    return replace(config, **changes)


def test_the_viewer_renders_what_the_run_renders_and_follows_its_controls(tiny, tmp_path):
    from glimpse.replay.finished import load_finished_run
    from glimpse.replay.render import Edits, render_shot, render_shot_passes
    from glimpse.view.camera import pinhole_from_viewer, render_size, viewer_from_pinhole
    from glimpse.view.session import NO_MOTION, ViewSession

    _, run_dir = tiny
    run = load_finished_run(run_dir)
    session = ViewSession(run, view_config(), torch.device("cpu"))
    camera = session.start_camera()
    back = pinhole_from_viewer(*viewer_from_pinhole(camera), camera.width, camera.height)
    assert np.allclose(back.R, camera.R, atol=1e-9) and np.allclose(back.t, camera.t, atol=1e-9)
    assert np.allclose(back.K, camera.K, atol=1e-9)  # the fixture's principal point is centred, as the browser's
    frame = session.state.frame_id
    shown = session.render(camera)
    assert np.array_equal(shown, render_shot(run, camera, frame, Edits(), torch.device("cpu")))
    p0 = render_shot_passes(run, camera, frame, Edits(), torch.device("cpu")).masks["p0"] > 1e-3
    assert p0.sum() > 20
    session.set_visible("p0", False)
    without = session.render(camera).astype(int)
    changed = np.abs(without - shown.astype(int)).max(axis=2) > 0
    assert changed[p0].mean() > 0.5 and not changed[~p0].any()  # only p0's pixels, most of them
    session.set_visible("p0", True)
    session.set_background(False)
    people = session.render(camera)
    alpha = render_shot_passes(run, camera, frame, Edits(background=False), torch.device("cpu")).alpha
    assert people[alpha < 1e-4].max() == 0 and people[alpha > 0.5].max() > 0
    session.set_background(True)
    session.set_motion("p0", "builtin:walk")
    start = session.render(camera).astype(int)
    for _ in range(20):
        session.step()
    assert session.state.motion_index == 20 and session.state.frame_id == frame  # the scene stays frozen
    assert np.abs(session.render(camera).astype(int) - start).max() > 50  # p0 walked
    session.set_motion("p0", NO_MOTION)
    assert np.array_equal(session.render(camera), shown)
    session.step()
    assert session.state.frame_id == session.frames[(session.frames.index(frame) + 1) % len(session.frames)]
    shot = session.screenshot(camera, tmp_path / "shots")
    assert Image.open(shot).size == render_size(camera.width, camera.height, session.config.still_max_side_px)
    assert session.screenshot(camera, tmp_path / "shots") != shot  # nothing is overwritten
    with pytest.raises(GlimpseError, match="no person 'p9'"):
        session.set_visible("p9", False)


def test_the_viewer_serves_a_browser_renders_its_camera_and_takes_its_clicks(tiny, tmp_path):
    from playwright.sync_api import sync_playwright

    from glimpse.replay.finished import load_finished_run
    from glimpse.view.server import ViewerServer
    from glimpse.view.session import ViewSession
    from tests.support.browser import free_port, launch

    _, run_dir = tiny
    session = ViewSession(load_finished_run(run_dir), view_config(sharp_after_s=0.1), torch.device("cpu"))
    viewer = ViewerServer(session, tmp_path / "shots", "127.0.0.1", free_port())
    try:
        with sync_playwright() as playwright:
            browser = launch(playwright, webgl=True)
            page = browser.new_page(viewport={"width": 640, "height": 480})
            page.goto(f"http://127.0.0.1:{viewer.port}")
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and not any(v.sharp for v in viewer.views.values()):
                page.wait_for_timeout(100)
            (view,) = viewer.views.values()
            assert view.sharp and view.last_size == (640, 480)  # the canvas, at most still_max_side_px
            page.wait_for_timeout(500)
            picture = np.asarray(Image.open(io.BytesIO(page.screenshot())).convert("RGB")).astype(int)
            assert picture[:, :300].std(axis=(0, 1)).max() > 20  # the scene, not an empty page
            page.get_by_role("button", name="save screenshot").click()
            page.get_by_role("checkbox", name="p0").click()
            deadline = time.monotonic() + 20
            while time.monotonic() < deadline and not (viewer.screenshots and session.state.hidden):
                page.wait_for_timeout(100)
            browser.close()
    finally:
        viewer.stop()
    assert session.state.hidden == {"p0"} and viewer.screenshots and viewer.screenshots[0].is_file()


def test_stage07_states_its_protocol_and_falls_back_to_the_input_view(tiny, tmp_path):
    scene, run_dir = tiny
    metrics = read_json(run_dir / "07_eval" / "metrics.json")
    assert metrics["views"].startswith("held-out")
    assert set(metrics["tables"]) == {"humans", "people", "seen", "never_seen", "composite"}
    for table in ("humans", "seen", "never_seen"):  # the render and both baselines, the render ahead of an empty one
        rows = {row["label"]: row for row in metrics["tables"][table]["rows"]}
        assert list(rows) == [RENDER_ROW, EMPTY_ROW, FLAT_ROW]
        assert rows[RENDER_ROW]["lpips"] < rows[EMPTY_ROW]["lpips"]
    assert metrics["tables"]["never_seen"]["rows"][0]["psnr"] > metrics["tables"]["never_seen"]["rows"][1]["psnr"]
    # seen and never-seen split each view's union mask: a view with people has seen pixels, so the seen table
    # scores at least the views the never-seen one does
    assert metrics["tables"]["seen"]["rows"][0]["n_frames"] >= metrics["tables"]["never_seen"]["rows"][0]["n_frames"]
    people = [row["label"] for row in metrics["tables"]["people"]["rows"]]
    assert people == [label for pid in ("p0", "p1") for label in (pid, person_flat_row(pid))]
    text = (run_dir / "07_eval" / "metrics.md").read_text()
    assert "Humans only" in text and "union of the people's masks" in text and "none of whose vertices" in text
    assert "Seen regions" in text and "less the never-seen pixels" in text
    summary = read_json(run_dir / "07_eval" / "manifest.json")["summary"]
    assert summary["seen_psnr_db"] == pytest.approx(metrics["tables"]["seen"]["rows"][0]["psnr"], abs=1e-3)
    out = run("07_eval", scene, run_dir.parent,
              SHORT + " 07_eval.heldout=input 07_eval.renders.enabled=false 07_eval.speed.enabled=false")
    assert "INPUT view" in read_json(out / "metrics.json")["views"]


def test_held_out_views_without_masks_are_scored_on_the_full_frame_only(tiny, tmp_path):
    import shutil

    scene, run_dir = tiny
    unmasked = tmp_path / "scene"
    shutil.copytree(scene, unmasked)
    for masks in unmasked.glob("eval/*/masks"):
        shutil.rmtree(masks)
    shutil.copytree(run_dir, tmp_path / "out" / run_dir.name, ignore=shutil.ignore_patterns("07_eval", ".lock"))
    params = SHORT + " 07_eval.renders.enabled=false 07_eval.speed.enabled=false"
    masked = read_json(run("07_eval", scene, tmp_path / "out", params) / "metrics.json")
    before = masked["tables"]["composite"]["rows"][0]
    out = run("07_eval", unmasked, tmp_path / "out", params)
    metrics = read_json(out / "metrics.json")
    assert set(metrics["tables"]) == {"composite"} and "no ground-truth masks" in metrics["views"]
    assert metrics["tables"]["composite"]["rows"][0]["psnr"] == pytest.approx(before["psnr"], abs=1e-4)
    summary = read_json(out / "manifest.json")["summary"]
    assert "humans_psnr_db" not in summary and summary["composite_psnr_db"] == pytest.approx(before["psnr"], abs=1e-3)
    assert "full frame: PSNR" in (tmp_path / "out" / run_dir.name / "report.html").read_text()


def test_a_finished_run_exports_a_scene_ply_that_renders_like_the_run(tiny, tmp_path, capsys):
    import pycolmap
    import trimesh

    from glimpse.cli import main as cli
    from glimpse.humans.compose import frame_gaussians, render_frame
    from glimpse.render import Camera, rasterize
    from glimpse.replay.cameras import mean_up
    from glimpse.replay.finished import load_finished_run

    _, run_dir = tiny
    assert cli(["export", str(run_dir), "--frame", "3", "--up", "keep", "--out", str(tmp_path / "export")]) == 0
    doc = read_json(tmp_path / "export" / "export.json")
    assert doc["frames"] == [3] and doc["scenes"] == ["scene_000003.ply"] and set(doc["people"]) == {"p0", "p1"}
    finished = load_finished_run(run_dir)
    camera = render_camera(finished.cameras[3], torch.device("cpu"))
    with torch.no_grad():
        gaussians = frame_gaussians(camera, 3, finished.people, RENDER.sh_degree, finished.background, RENDER.sh_degree)
        expected = render_frame(camera, gaussians, len(finished.people), RENDER).rgb
        scene = GaussianModel.from_splats(read_gaussians_ply(tmp_path / "export" / doc["scenes"][0])[0])
        exported = rasterize(camera, **scene.render_inputs(RENDER.sh_degree), settings=RENDER).rgb
    # The PLY holds float32 logits and log-scales: a round trip can move a Gaussian across the rasterizer's alpha
    # cutoff (ALPHA_MIN, 1/255) at a pixel, which changes that pixel by at most about the cutoff; a wrong convention
    # (a scale, a colour, a rotation) would move most pixels.
    difference = (exported - expected).abs()
    assert len(scene) == len(gaussians.means) and difference.max() < ALPHA_MIN
    assert (difference > 1e-4).float().mean() < 1e-3
    for pid in ("p0", "p1"):
        assert "posed_000003.ply" in doc["people"][pid]["files"] and "mesh_000003.glb" in doc["people"][pid]["files"]
        canonical, _ = read_gaussians_ply(tmp_path / "export" / "people" / pid / "canonical.ply")
        assert len(canonical) == doc["people"][pid]["gaussians"]
        # the body mesh, read by trimesh: the exported body.npz posed by the body model at frame 3, coloured
        mesh = trimesh.load(tmp_path / "export" / "people" / pid / "mesh_000003.glb", force="mesh", process=False)
        body = read_body_params(tmp_path / "export" / "people" / pid / "body.npz")
        row = list(body.frame_ids).index(3)
        posed = finished.body_models[pid](body.betas[None], body.global_orient[row:row + 1],
                                          body.body_pose[row:row + 1], body.transl[row:row + 1],
                                          [body.scale]).vertices[0].numpy()
        assert np.abs(np.asarray(mesh.vertices) - posed).max() < 1e-5
        assert len(mesh.faces) == len(finished.body_models.faces)
        colours = np.asarray(mesh.visual.vertex_colors)[:, :3].astype(float)
        assert colours.std(axis=0).min() > 5  # coloured by the Gaussians, not one flat colour
    model = pycolmap.Reconstruction(str(tmp_path / "export" / "cameras"))  # COLMAP's own reader
    assert len(model.images) == len(finished.cameras)
    image = next(i for i in model.images.values() if i.name == "000003.png")
    assert np.allclose(image.cam_from_world().rotation.matrix(), finished.cameras[3].R, atol=1e-6)
    assert model.cameras[image.camera_id].width == finished.width

    # a sequence, turned y-up (the default): the scene and its COLMAP cameras turn together, so the exported
    # camera sees the exported frame as the run's camera saw the run (positions, orientations, SH colours)
    assert cli(["export", str(run_dir), "--frames", "2:3", "--out", str(tmp_path / "sequence")]) == 0
    doc = read_json(tmp_path / "sequence" / "export.json")
    turn = np.array(doc["world_rotation"])
    assert doc["up"] == "y" and doc["scenes"] == ["scene_000002.ply", "scene_000003.ply"]
    assert np.allclose(turn @ mean_up(list(finished.cameras.values())), [0.0, 1.0, 0.0], atol=1e-9)
    model = pycolmap.Reconstruction(str(tmp_path / "sequence" / "cameras"))
    image = next(i for i in model.images.values() if i.name == "000003.png")
    pose = image.cam_from_world()
    assert np.allclose(pose.rotation.matrix(), finished.cameras[3].R @ turn.T, atol=1e-6)
    turned_camera = Camera(camera.K, torch.as_tensor(pose.rotation.matrix(), dtype=torch.float32),
                           torch.as_tensor(pose.translation, dtype=torch.float32), camera.width, camera.height)
    with torch.no_grad():
        scene = GaussianModel.from_splats(read_gaussians_ply(tmp_path / "sequence" / "scene_000003.ply")[0])
        exported = rasterize(turned_camera, **scene.render_inputs(RENDER.sh_degree), settings=RENDER).rgb
    assert (exported - expected).abs().max() < 1e-3
    kept = trimesh.load(tmp_path / "export" / "people" / "p0" / "mesh_000003.glb", force="mesh", process=False)
    turned = trimesh.load(tmp_path / "sequence" / "people" / "p0" / "mesh_000003.glb", force="mesh", process=False)
    assert np.abs(np.asarray(turned.vertices) - np.asarray(kept.vertices) @ turn.T).max() < 1e-5
    assert cli(["export", str(tmp_path / "nothing")]) == EXIT_BAD_INPUT
    assert "no finished stage 06" in capsys.readouterr().err


def test_a_finished_run_renders_from_any_camera_with_people_removed(tiny, tmp_path, capsys):
    from glimpse.cli import main as cli
    from glimpse.io.video import read_mp4
    from glimpse.replay.finished import load_finished_run
    from glimpse.replay.render import Edits, render_shot

    scene, run_dir = tiny
    assert cli(["render", str(run_dir), "--time", "0:3", "--out", str(tmp_path / "input.mp4")]) == 0
    assert len(read_mp4(tmp_path / "input.mp4")) == 4
    assert cli(["render", str(run_dir), "--camera", "heldout:cam00", "--scene", str(scene), "--time", "2",
                "--out", str(tmp_path / "held")]) == 0  # orbits: stage 07's videos and tests/test_replay.py
    assert len(list((tmp_path / "held").glob("*.png"))) == 1
    assert cli(["render", str(run_dir), "--remove", "p9"]) == EXIT_BAD_INPUT and "the run's people are p0, p1" in capsys.readouterr().err
    assert cli(["render", str(run_dir), "--time", "1", "--motion", "p0=builtin:walk", "--motion-seconds", "0.3",
                "--fps", "10", "--out", str(tmp_path / "walk")]) == 0  # a frozen scene, p0 walks 3 frames
    walked = [np.asarray(Image.open(f)).astype(int) for f in sorted((tmp_path / "walk").glob("*.png"))]
    assert len(walked) == 3 and np.abs(walked[2] - walked[0]).max() > 50

    finished = load_finished_run(run_dir)
    shot, cpu = finished.cameras[3], torch.device("cpu")
    full = render_shot(finished, shot, 3, Edits(), cpu).astype(int)
    without_p1 = render_shot(finished, shot, 3, Edits(frozenset({"p1"})), cpu).astype(int)
    p1_alone = render_shot(finished, shot, 3, Edits(frozenset({"p0"}), background=False), cpu).max(-1) > 0
    p0_alone = render_shot(finished, shot, 3, Edits(frozenset({"p1"}), background=False), cpu).max(-1) > 0
    assert p1_alone.sum() > 20
    changed = np.abs(full - without_p1).max(-1) > 10
    assert changed[p1_alone & ~p0_alone].mean() > 0.5  # where p1 was, the background (or p0) shows now
    assert not changed[~p1_alone].any()  # nothing else moves


def test_render_passes_are_exr_beside_the_pngs_with_linear_colour_alpha_depth_and_visible_masks(tiny, tmp_path):
    from glimpse.cli import main as cli
    from glimpse.io.exr import read_exr, srgb_to_linear
    from glimpse.replay.finished import load_finished_run
    from glimpse.replay.render import pelvis

    scene, run_dir = tiny
    assert cli(["render", str(run_dir), "--time", "3", "--passes", "rgb,depth,alpha,mask",
                "--out", str(tmp_path / "frames")]) == 0
    channels, header = read_exr(tmp_path / "frames_exr" / "000000.exr")
    assert sorted(channels) == ["A", "B", "G", "R", "Z", "mask.p0", "mask.p1"]
    assert header["glimpse_depth_units"] == "metres"
    png = np.asarray(Image.open(tmp_path / "frames" / "000000.png")) / 255.0
    linear = np.stack([channels[c] for c in "RGB"], axis=-1)
    assert np.abs(linear - srgb_to_linear(png)).max() < 0.01  # the PNG's colours, linear, to 8-bit rounding
    alpha, masks = channels["A"], channels["mask.p0"] + channels["mask.p1"]
    assert alpha.min() >= 0.0 and alpha.max() <= 1.0 + 1e-5 and (masks <= alpha + 1e-5).all()
    finished = load_finished_run(run_dir)
    camera = finished.cameras[3]
    for person in finished.people:
        centre_z = (camera.R @ pelvis(person, 3) + camera.t)[2]
        own = channels[f"mask.{person.pid}"] > 0.9
        assert own.sum() > 5 and abs(np.median(channels["Z"][own]) - centre_z) < 0.3  # metres: the body's depth
    assert cli(["render", str(run_dir), "--passes", "rgb,normals"]) == EXIT_BAD_INPUT


def _one_view_trainer(body_model, tmp_path, config, lpips_module=None, box=None, lpips_target_cache_mb=0.0):
    """A factory of JointTrainers of one person seen in one random 48x64 frame (each call starts afresh)."""
    from glimpse.io.frame_cache import FrameCache
    from glimpse.joint.train import JointTrainer, JointView
    from glimpse.render import Camera

    body = BodyParams(np.array([0]), np.zeros(10), np.array([[math.pi, 0.0, 0.0]]), np.zeros((1, 69)),
                      np.array([[0.0, 0.0, 3.0]]), 1.0, "free", np.zeros(1, bool))
    camera = Camera(torch.tensor([[40.0, 0, 23.5], [0, 40.0, 31.5], [0, 0, 1]]), torch.eye(3), torch.zeros(3), 48, 64)
    image = torch.as_tensor(np.random.default_rng(0).integers(0, 255, (64, 48, 3)), dtype=torch.uint8)
    pixels = FrameCache(lambda _: (image, torch.ones(64, 48, dtype=torch.bool), box, {}), capacity=1)
    views = [JointView(0, camera, pixels.get)]

    pinhole = PinholeCamera(camera.K.double().numpy(), np.eye(3), np.zeros(3), 48, 64)
    visibility = body_visibility(BodyModels(body_model), {"p0": body}, {0: pinhole}, 48, 64, {}, JOINT.visibility)
    surface = replace(SURFACE, views_per_person=2, start_at=1000, refresh_every=2500)  # from iteration 2, every 5

    def trainer() -> JointTrainer:
        person = initial_person("p0", body_model, body, 30.0, BODY.skinning, 0.5, 0.9, 3, 1)
        background = GaussianModel.from_points(torch.tensor([[0.0, 0.0, 10.0]]), torch.full((1, 3), 0.3),
                                               torch.tensor([5.0]), 0.5, 1)
        prior = make_prior("surface", PriorContext([person], visibility, BodyModels(body_model), RENDER, 0,
                                                   config.scaled),
                           surface)
        return JointTrainer(background, [person], views, config, RENDER, prior, lpips_module, 0,
                            tmp_path / "checkpoint.pt", "key", lpips_target_cache_mb)

    return trainer


def test_a_resumed_run_ends_as_an_uninterrupted_one(body_model, tmp_path):
    """Train 24 iterations (densification and pruning included) with checkpoints every 10; a second trainer
    started from the same initial state resumes from the iteration-20 checkpoint and ends identical."""
    config = replace(JOINT, schedule_scale=0.002, checkpoint_every=10, loss=replace(JOINT.loss, lpips=0.0))
    trainer = _one_view_trainer(body_model, tmp_path, config)

    first = trainer()
    first.run()
    assert any("cloned" in e for e in first.log.densify_events)
    second = trainer()
    log = second.run()
    assert log.resumed_from == 20 and log.iterations_run == 4
    for a, b in zip(first.people[0].model.parameter_dict().values(), second.people[0].model.parameter_dict().values()):
        assert torch.equal(a, b)
    assert torch.equal(first.people[0].pose_offsets, second.people[0].pose_offsets)
    assert torch.equal(first.background.sh_dc, second.background.sh_dc)


def test_the_lpips_target_is_kept_with_the_frame_while_its_budget_lasts(body_model, tmp_path):
    """The frame's LPIPS target features are computed once and kept when they fit compute.lpips_target_cache_mb,
    recomputed (the same values) when they do not."""
    from glimpse.metrics.lpips import LPIPS

    lpips_module = LPIPS("alex")
    box = (8, 56, 4, 44)
    for budget_mb, kept in ((1.0, True), (0.01, False)):
        trainer = _one_view_trainer(body_model, tmp_path, JOINT, lpips_module, box, budget_mb)()
        view = trainer.views[0]
        first, again = trainer._lpips_target(view), trainer._lpips_target(view)
        assert (first is again) == kept and all(torch.equal(a, b) for a, b in zip(first, again, strict=True))
        assert sum(f.numel() * 4 for f in first) > 0.01 * 2**20


def test_a_held_out_frame_of_the_input_video_is_scored_with_people_posed_between_its_neighbours(tiny, tmp_path):
    import shutil

    from glimpse.body.params import write_body_params

    scene, run_dir = tiny
    for copy in ("given", "between"):  # stage 07 again on copies: other tests rerun it in the shared run folder
        shutil.copytree(run_dir, tmp_path / copy / run_dir.name, ignore=shutil.ignore_patterns("07_eval", ".lock"))
    held = 4  # a frame with held-out images, as if stage 06 never had it: people posed there from frames 3 and 5
    for path in (tmp_path / "between" / run_dir.name / "06_joint_opt" / "humans").glob("*/body.npz"):
        body = read_body_params(path)
        write_body_params(path, body.select([f for f in body.frame_ids if f != held]))
    params = SHORT + " 07_eval.heldout=auto 07_eval.renders.enabled=false 07_eval.speed.enabled=false"
    given, between = (read_json(run("07_eval", scene, tmp_path / copy, params) / "metrics.json")["tables"]["humans"]
                      ["rows"] for copy in ("given", "between"))

    def at_held(rows: list, k: int) -> list[dict]:
        return [f for f in rows[k]["frames"] if f["frame"].endswith(f"/{held:06d}")]

    assert at_held(between, 0) and len(at_held(between, 0)) == len(at_held(given, 0))
    for interpolated, exact, empty in zip(at_held(between, 0), at_held(given, 0), at_held(between, 1)):
        assert abs(interpolated["psnr"] - exact["psnr"]) < 1.0  # neighbours' poses, nearly the frame's own
        assert interpolated["lpips"] < 0.5 * empty["lpips"]  # the people are drawn there, not left out
