"""Stage 01 on synthetic rooms rendered by tests/support/synthetic_room.py (a numpy
ray caster, not anything the pipeline uses), checked against the true cameras."""

import json

import numpy as np
import pytest

from glimpse.cameras.align import umeyama
from glimpse.io.cameras_json import read_cameras_json
from glimpse.io.ply_points import read_points_ply
from tests.stage_helpers import read_json, run
from tests.support.synthetic_room import ROOM_MAX, ROOM_MIN, make_room_scene


def wall_gap(xyz: np.ndarray) -> np.ndarray:
    """(N,) distance of each point to the nearest wall plane of the room (metres)."""
    return np.minimum(np.abs(xyz - np.array(ROOM_MIN)), np.abs(xyz - np.array(ROOM_MAX))).min(axis=1)


def centre_errors(cameras, truth, align: bool) -> np.ndarray:
    ids = sorted(truth.R)
    est = np.array([cameras[i].centre for i in ids])
    ref = np.array([truth.centres()[i] for i in ids])
    if align:
        est = umeyama(est, ref).apply(est)
    return np.linalg.norm(est - ref, axis=1)


@pytest.fixture(scope="module")
def masked_run(tmp_path_factory):
    """Forced SfM on a moving camera whose poses are given: aligned to them, error reported."""
    root = tmp_path_factory.mktemp("masked")
    truth = make_room_scene(root / "scene", write_cameras="poses", camera_motion="moving")
    out = run("01_sfm", root / "scene", root / "out", "01_sfm.mode=sfm")
    return truth, out


def test_sfm_registers_every_frame_within_a_centimetre(masked_run):
    truth, out = masked_run
    report = read_json(out / "report.json")
    assert report["mode"] == "sfm" and report["frames_without_camera"] == []
    assert report["sfm"]["masking"] == ["masks"] and report["warnings"] == []
    width, height, cameras = read_cameras_json(out / "cameras.json")
    assert (width, height) == (truth.width, truth.height) and sorted(cameras) == sorted(truth.R)
    errors = centre_errors(cameras, truth, align=False)  # already aligned to the given cameras
    assert errors.max() < 0.01, errors
    assert report["sfm"]["error"]["centre_max_m"] == pytest.approx(errors.max(), abs=1e-6)
    assert report["units"] == "metres"


def test_an_unknown_focal_length_is_estimated_within_two_percent(tmp_path):
    """Intrinsics withheld (a 75-degree camera; SfM starts from the 60-degree default, 25% off): the focal
    length comes from the frame pairs before mapping and the last bundle adjustment; centres within 2 cm."""
    truth = make_room_scene(tmp_path / "scene", write_cameras="poses", camera_motion="moving", fov_deg=75.0)
    out = run("01_sfm", tmp_path / "scene", tmp_path / "out", "01_sfm.mode=sfm 01_sfm.estimate_focal=true")
    report = read_json(out / "report.json")["sfm"]
    assert report["intrinsics"] == "estimated" and report["registered"] == len(truth.R)
    calibration = report["self_calibration"]
    assert calibration["pairs"] >= 10 and calibration["focal_px"] == pytest.approx(truth.K[0, 0], rel=0.05)
    assert abs(report["error"]["focal_relative"]) < 0.02 and report["error"]["centre_rms_m"] < 0.02
    _, _, cameras = read_cameras_json(out / "cameras.json")
    assert next(iter(cameras.values())).K[0, 0] == pytest.approx(truth.K[0, 0], rel=0.02)


def test_sfm_outputs_points_colmap_and_timings(masked_run):
    truth, out = masked_run
    xyz, rgb = read_points_ply(out / "points.ply")
    assert len(xyz) > 500 and rgb.dtype == np.uint8
    # points lie on the room's walls (the person is masked out of extraction)
    gap = wall_gap(xyz)  # sparse depth noise grows with distance (up to 10 m at 320x240)
    assert np.median(gap) < 0.02 and (gap < 0.05).mean() > 0.8
    images = (out / "colmap" / "images.txt").read_text().splitlines()
    assert len([line for line in images if line and not line.startswith("#")]) == len(truth.R)
    assert (out / "colmap" / "cameras.txt").read_text().count("PINHOLE") == 1
    manifest = read_json(out / "manifest.json")
    assert {"extraction", "matching", "mapping"} <= set(manifest["timings_s"])
    assert manifest["formats"]["cameras.json"] == "glimpse-cameras/1"
    assert sorted(p.name for p in (out / "frames").iterdir())[:2] == ["000000.png", "000001.png"]


def test_without_masks_the_walking_person_damages_the_cameras(masked_run, tmp_path):
    truth, masked_out = masked_run
    masked_error = read_json(masked_out / "report.json")["sfm"]["error"]["centre_rms_m"]
    make_room_scene(tmp_path / "scene", with_masks=False, write_cameras="poses", camera_motion="moving")
    out = run("01_sfm", tmp_path / "scene", tmp_path / "out", "01_sfm.mode=sfm")
    report = read_json(out / "report.json")
    assert any("moving people may corrupt the camera poses" in w for w in report["warnings"])
    assert report["sfm"]["masking"] == []
    unmasked_error = report["sfm"]["error"]["centre_rms_m"]
    assert unmasked_error > 5 * masked_error and unmasked_error > 0.005, (masked_error, unmasked_error)


def write_keypoints_from_masks(scene) -> None:
    """Replace the person's masks by COCO-17 keypoints spread over each mask's bounding box
    (confidence 0 where the person is out of view), as a 2D detector would give."""
    from glimpse.io.images import read_mask

    mask_dir = scene / "humans" / "p0" / "masks"
    paths = sorted(mask_dir.iterdir())
    keypoints = np.zeros((len(paths), 17, 3))
    grid = np.stack(np.meshgrid(np.linspace(0, 1, 3), np.linspace(0, 1, 6)), -1).reshape(-1, 2)[:17]
    for i, path in enumerate(paths):
        ys, xs = np.nonzero(read_mask(path))
        if len(xs):
            lo, hi = np.array([xs.min(), ys.min()]), np.array([xs.max(), ys.max()])
            keypoints[i, :, :2] = lo + grid * (hi - lo)
            keypoints[i, :, 2] = 1.0
        path.unlink()
    mask_dir.rmdir()
    np.savez(scene / "humans" / "p0" / "keypoints2d.npz", frame_ids=np.arange(len(paths)),
             layout=np.array("coco17"), keypoints=keypoints)


def test_keypoint_boxes_stand_in_for_missing_masks(masked_run, tmp_path):
    make_room_scene(tmp_path / "scene", write_cameras="poses", camera_motion="moving")
    write_keypoints_from_masks(tmp_path / "scene")
    out = run("01_sfm", tmp_path / "scene", tmp_path / "out", "01_sfm.mode=sfm")
    report = read_json(out / "report.json")
    assert report["sfm"]["masking"] == ["keypoint boxes"] and report["warnings"] == []
    assert report["sfm"]["error"]["centre_max_m"] < 0.01


def test_unknown_motion_is_measured_moving_and_sfm_keeps_its_own_frame(tmp_path):
    truth = make_room_scene(tmp_path / "scene", n_frames=16, camera_motion="unknown")
    out = run("01_sfm", tmp_path / "scene", tmp_path / "out")
    report = read_json(out / "report.json")
    assert report["mode"] == "sfm" and report["camera_motion"] == "moving" and report["units"] == "sfm"
    assert report["motion"]["measure"] > report["motion"]["threshold"]
    assert report["sfm"]["intrinsics"] == "estimated"
    _, _, cameras = read_cameras_json(out / "cameras.json")
    assert centre_errors(cameras, truth, align=True).max() < 0.01
    K = next(iter(cameras.values())).K
    assert K[0, 0] == pytest.approx(truth.K[0, 0], rel=0.01) and K[0, 0] == K[1, 1]  # one focal (square pixels)
    again = run("01_sfm", tmp_path / "scene", tmp_path / "again")  # same inputs, same artifacts
    for name in ("cameras.json", "points.ply", "colmap/images.txt", "report.json"):
        assert (out / name).read_bytes() == (again / name).read_bytes(), name


def test_unknown_motion_of_a_static_camera_gives_the_static_mode(tmp_path):
    make_room_scene(tmp_path / "scene", n_frames=6, camera="static", camera_motion="unknown")
    out = run("01_sfm", tmp_path / "scene", tmp_path / "out")
    report = read_json(out / "report.json")
    assert report["mode"] == "static" and report["motion"]["measure"] < report["motion"]["threshold"]
    _, _, cameras = read_cameras_json(out / "cameras.json")
    assert len(cameras) == 6 and not (out / "points.ply").exists()
    cam = cameras[0]
    assert np.allclose(cam.R, np.eye(3)) and np.allclose(cam.t, 0)
    assert cam.K[0, 0] == pytest.approx(0.5 * 320 / np.tan(np.radians(60.0) / 2))  # static_fov_deg default
    assert cam.K[0, 2] == pytest.approx(159.5) and cam.K[1, 2] == pytest.approx(119.5)


def test_provided_moving_cameras_get_triangulated_points(tmp_path):
    truth = make_room_scene(tmp_path / "scene", n_frames=12, write_cameras="poses")
    out = run("01_sfm", tmp_path / "scene", tmp_path / "out")
    report = read_json(out / "report.json")
    assert report["mode"] == "provided" and report["camera_motion"] == "moving"
    _, _, cameras = read_cameras_json(out / "cameras.json")
    for fid, cam in cameras.items():
        assert np.allclose(cam.R, truth.R[fid]) and np.allclose(cam.t, truth.t[fid])
    xyz, _ = read_points_ply(out / "points.ply")
    gap = wall_gap(xyz)
    assert len(xyz) > 300 and np.median(gap) < 0.02 and (gap < 0.05).mean() > 0.8


def test_fps_and_max_frames_subsample_and_keep_ids(tmp_path):
    make_room_scene(tmp_path / "scene", n_frames=9, width=64, height=48, camera="static")
    out = run("01_sfm", tmp_path / "scene", tmp_path / "out", "01_sfm.fps=5 01_sfm.max_frames=4")
    _, _, cameras = read_cameras_json(out / "cameras.json")
    assert sorted(cameras) == [0, 2, 4, 6]  # scene fps 10 -> every 2nd frame, first 4
    assert json.loads((out / "report.json").read_text())["frames"] == 4
