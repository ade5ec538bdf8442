"""Stage 01: video decoding, undistortion, clear failures, and the make entry points."""

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest
import yaml

from glimpse.errors import GlimpseError
from glimpse.io.cameras_json import read_cameras_json
from glimpse.io.images import read_rgb
from glimpse.pipeline.stages import STAGE_NAMES
from tests.stage_helpers import REPO, read_json, run
from tests.support.synthetic_room import make_room_scene


def test_video_frames_are_decoded_subsampled_and_keep_their_indices(tmp_path):
    make_room_scene(tmp_path / "src", n_frames=10, width=64, height=48, with_person=False)
    scene = tmp_path / "scene"
    scene.mkdir()
    (scene / "scene.yaml").write_text((tmp_path / "src" / "scene.yaml").read_text())
    writer = cv2.VideoWriter(str(scene / "video.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 10, (64, 48))
    originals = [read_rgb(tmp_path / "src" / "frames" / f"{i:06d}.png") for i in range(10)]
    for image in originals:
        writer.write(cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    writer.release()
    out = run("01_sfm", scene, tmp_path / "out", "01_sfm.fps=3.4 01_sfm.mode=static")
    names = sorted(p.name for p in (out / "frames").iterdir())
    assert names == ["000000.png", "000003.png", "000006.png", "000009.png"]  # every 3rd frame, ids kept
    for fid in (0, 3, 6, 9):  # each written frame is the video frame of its index (lossy codec)
        decoded = read_rgb(out / "frames" / f"{fid:06d}.png").astype(float)
        differences = [np.abs(decoded - original).mean() for original in originals]
        assert int(np.argmin(differences)) == fid and differences[fid] < 20, differences
    _, _, cameras = read_cameras_json(out / "cameras.json")
    assert sorted(cameras) == [0, 3, 6, 9]


def test_distorted_frames_are_undistorted_once(tmp_path):
    truth = make_room_scene(tmp_path / "scene", n_frames=2, camera="static", with_person=False)
    scene = tmp_path / "scene"
    K, dist = truth.K, np.array([-0.25, 0.08, 0.001, -0.001])
    # distort each frame: pixel p of the distorted image shows undistorted pixel undistort(p)
    h, w = truth.height, truth.width
    grid = np.stack(np.meshgrid(np.arange(w), np.arange(h)), -1).reshape(-1, 1, 2).astype(np.float64)
    source = cv2.undistortPoints(grid, K, dist, P=K).reshape(h, w, 2).astype(np.float32)
    clean = {}
    for fid in (0, 1):
        path = scene / "frames" / f"{fid:06d}.png"
        clean[fid] = read_rgb(path)
        distorted = cv2.remap(clean[fid], source[..., 0], source[..., 1], cv2.INTER_LINEAR)
        cv2.imwrite(str(path), cv2.cvtColor(distorted, cv2.COLOR_RGB2BGR))
    cams = {"format": "glimpse-cameras/1", "width": w, "height": h, "K": K.tolist(), "dist": dist.tolist()}
    (scene / "cameras.json").write_text(json.dumps(cams))
    out = run("01_sfm", scene, tmp_path / "out")
    restored = read_rgb(out / "frames" / "000000.png").astype(float)
    inner = (slice(h // 6, -h // 6), slice(w // 6, -w // 6))
    before = np.abs(read_rgb(scene / "frames" / "000000.png").astype(float) - clean[0])[inner].mean()
    after = np.abs(restored - clean[0])[inner].mean()
    assert after < 0.3 * before and after < 8, (before, after)
    report = read_json(out / "report.json")
    assert report["undistorted"] is True and report["mode"] == "static"
    _, _, cameras = read_cameras_json(out / "cameras.json")
    assert np.allclose(cameras[0].K, K)  # pinhole with the same K from here on


def test_too_few_registered_frames_fail_clearly_and_keep_nothing(tmp_path):
    make_room_scene(tmp_path / "scene", n_frames=12, camera_motion="moving")
    blank = np.full((240, 320, 3), 128, np.uint8)  # a frame with no features cannot register
    cv2.imwrite(str(tmp_path / "scene" / "frames" / "000011.png"), blank)
    with pytest.raises(GlimpseError, match=r"registered 11 of 12 frames.*unregistered: 11"):
        run("01_sfm", tmp_path / "scene", tmp_path / "out", "01_sfm.min_registered_fraction=1.0")
    assert not (tmp_path / "out" / "room" / "01_sfm").exists()
    out = run("01_sfm", tmp_path / "scene", tmp_path / "out")  # the default fraction (0.9) accepts it
    assert read_json(out / "report.json")["frames_without_camera"] == [11]


def _make(*args, cwd=REPO):
    return subprocess.run(["make", "-C", str(cwd), f"PY={sys.executable}", *args],
                          capture_output=True, text=True, timeout=600)


def test_make_demo_runs_every_stage_prints_the_metrics_and_a_change_reruns_only_what_follows(tmp_path):
    """`make demo` (glimpse.demo: the scene generated once, then `make all`), then `make all` on its scene with
    one stage-07 parameter changed."""
    short = "04_bg_pretrain.schedule_scale=0.01 06_joint_opt.schedule_scale=0.005 07_eval.renders.enabled=false "\
            "07_eval.speed.enabled=false"
    result = subprocess.run([sys.executable, "-m", "glimpse.demo", "--out", str(tmp_path), "--size", "tiny",
                             "--params", short], cwd=REPO, capture_output=True, text=True, timeout=600)
    run_dir = tmp_path / "demo_tiny"
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr
    assert "the whole pipeline ran" in result.stdout
    assert "| humans only |" in result.stdout and "Protocol" not in result.stdout
    stamps = {stage: (run_dir / stage / "manifest.json").stat().st_mtime_ns for stage in STAGE_NAMES}
    result = _make("all", f"SCENE={tmp_path / 'scenes' / 'demo_tiny'}", f"OUT={tmp_path}",
                   f"PARAMS={short} 07_eval.input_view_every=2")
    assert result.returncode == 0, result.stderr
    changed = {stage for stage in STAGE_NAMES if (run_dir / stage / "manifest.json").stat().st_mtime_ns != stamps[stage]}
    assert changed == {"07_eval"}


def test_broken_scene_is_refused_with_every_problem_and_no_traceback(tmp_path):
    make_room_scene(tmp_path / "scene", n_frames=3, width=32, height=24, camera="static")
    scene = tmp_path / "scene"
    config = yaml.safe_load((scene / "scene.yaml").read_text())
    config["camera_motion"] = "sideways"
    (scene / "scene.yaml").write_text(yaml.safe_dump(config))
    (scene / "frames" / "notes.txt").write_text("stray")
    for target in ("validate", "all"):
        result = _make(target, f"SCENE={scene}", f"OUT={tmp_path / 'out'}")
        assert result.returncode != 0
        assert "scene.yaml: " in result.stderr and "camera_motion" in result.stderr
        assert "frames/notes.txt" in result.stderr
        assert "Traceback" not in result.stderr
    assert not (tmp_path / "out" / "room").exists()
