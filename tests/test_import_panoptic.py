"""CMU Panoptic import on a miniature copy of a sequence's layout (calibration JSON in centimetres with HD and
VGA cameras, hdImgs/ JPEGs for some cameras and an hdVideos/ MP4 for another, coco19 body files with -1
confidences): the imported cameras and 3D keypoints must agree with the source, projected with the toolbox's
own distortion formula; stage 02 fits the free body to the coco19 keypoints."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import torch
from PIL import Image

from glimpse.body.keypoints import keypoint_map
from glimpse.body.model import BodyModel
from glimpse.config import REPO_ROOT
from glimpse.errors import GlimpseError
from glimpse.importers import import_dataset
from glimpse.importers.common import ImportOptions, parse_span
from glimpse.io.video import read_mp4, write_mp4
from glimpse.scene import load_scene
from tests.stage_helpers import read_json, run

WIDTH, HEIGHT = 96, 72
FRAMES = range(100, 106)  # HD frames that have bodies
VIDEO_FRAMES = 106  # hd_00_03.mp4 holds HD frames 0..105
FREE_BODY = REPO_ROOT / "glimpse" / "body" / "assets" / "free_body.npz"


def look_at(centre, target):
    """World-to-camera R, t (metres) of an OpenCV camera; Panoptic's world has up -y, so image down is +y."""
    z = (target - centre) / np.linalg.norm(target - centre)
    x = np.cross(np.array([0.0, 1.0, 0.0]), z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    return R, -R @ centre


def toolbox_project(points_m, camera) -> np.ndarray:
    """The panoptic-toolbox's projection (its MATLAB PoseProject2D), in centimetres as the toolbox works."""
    X = points_m * 100.0 @ np.asarray(camera["R"]).T + np.asarray(camera["t"]).reshape(3)
    x, y = X[:, 0] / X[:, 2], X[:, 1] / X[:, 2]
    k1, k2, p1, p2, k3 = camera["distCoef"]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + 2 * p2 * x * y + p1 * (r2 + 2 * y * y)
    K = np.asarray(camera["K"])
    return np.stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=1)


def body_joints(model: BodyModel, seed: int, offset: np.ndarray) -> np.ndarray:
    """[19, 3] coco19 keypoints (metres, y down as Panoptic's world) of the free body in a random pose (one per
    seed: a person holds it while moving)."""
    kmap = keypoint_map("coco19", model.data)
    pose = torch.as_tensor(np.random.default_rng(seed).normal(0, 0.15, (1, 69)))
    flip = torch.tensor([[np.pi, 0.0, 0.0]], dtype=torch.float64)  # the body's +y up -> the world's -y up
    out = model(torch.zeros(1, 10, dtype=torch.float64), flip, pose)
    return kmap(out.joints, out.vertices)[0].numpy() + offset


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    root = tmp_path_factory.mktemp("panoptic")
    folder = root / "160422_ultimatum1"
    rng = np.random.default_rng(0)
    cameras = []
    for node, angle in ((16, 0.0), (0, 2.1), (3, -2.0)):
        centre = np.array([3.0 * np.sin(angle), -1.2, -3.0 * np.cos(angle)])
        R, t = look_at(centre, np.array([0.0, -0.9, 0.0]))
        cameras.append({"name": f"00_{node:02d}", "type": "hd", "panel": 0, "node": node,
                        "K": [[80.0 + node, 0, 47.2], [0, 81.0 + node, 35.9], [0, 0, 1]],
                        "distCoef": [-0.25, 0.08, 0.001, -0.0015, -0.01], "R": R.tolist(),
                        "t": (t * 100.0).reshape(3, 1).tolist()})
    cameras.append({"name": "01_01", "type": "vga", "panel": 1, "node": 1, "K": np.eye(3).tolist(),
                    "distCoef": [0] * 5, "R": np.eye(3).tolist(), "t": [[0], [0], [0]]})
    folder.mkdir()
    (folder / f"calibration_{folder.name}.json").write_text(json.dumps({"cameras": cameras}))
    for name in ("00_16", "00_00"):
        (folder / "hdImgs" / name).mkdir(parents=True)
        for f in FRAMES:
            Image.fromarray(rng.integers(0, 255, (HEIGHT, WIDTH, 3), np.uint8)).save(
                folder / "hdImgs" / name / f"{name}_{f:08d}.jpg", quality=95)
    (folder / "hdVideos").mkdir()
    video = [np.full((HEIGHT, WIDTH, 3), (f * 2) % 256, np.uint8) for f in range(VIDEO_FRAMES)]
    write_mp4(folder / "hdVideos" / "hd_00_03.mp4", video, 29.97)
    model = BodyModel.from_file(FREE_BODY, dtype=torch.float64)
    (folder / "hdPose3d_stage1_coco19").mkdir()
    truth = {}
    for f in FRAMES:
        bodies = []
        for body_id, offset in ((0, np.array([-0.4, 0.0, 0.0])), (3, np.array([0.5, 0.0, 0.3]))):
            joints = body_joints(model, body_id, offset + [0.02 * (f - 100), 0, 0])
            confidence = np.full(19, 0.8)
            confidence[16] = -1.0  # a joint the studio did not reconstruct
            truth[(body_id, f)] = np.concatenate([joints, confidence[:, None]], axis=1)
            bodies.append({"id": body_id, "joints19": np.concatenate([joints * 100.0, confidence[:, None]],
                                                                     axis=1).reshape(-1).tolist()})
        (folder / "hdPose3d_stage1_coco19" / f"body3DScene_{f:08d}.json").write_text(
            json.dumps({"version": 0.7, "univTime": 0.0, "fpsType": "hd_29_97", "bodies": bodies}))
    scene = import_dataset("panoptic", root, root / "scene",
                           ImportOptions(sequence=folder.name, cameras=("16", "0", "3"), frames=parse_span("101:106"),
                                         eval_every=2))
    return folder, {c["name"]: c for c in cameras}, truth, scene


def test_cameras_keypoints_and_views_agree_with_the_source(imported):
    folder, cameras, truth, scene_dir = imported
    scene = load_scene(scene_dir)
    assert scene.frame_ids == [101, 102, 103, 104, 105] and scene.fps == pytest.approx(29.97)
    points = np.ascontiguousarray(truth[(0, 101)][:5, :3])
    pose = scene.cameras.poses[101]
    ours, _ = cv2.projectPoints(points, cv2.Rodrigues(pose.R)[0], pose.t, scene.cameras.K, scene.cameras.dist)
    assert np.abs(ours.reshape(-1, 2) - toolbox_project(points, cameras["00_16"])).max() < 1e-6
    held = scene.eval_cameras["hd_00_03"]
    pinhole, _ = cv2.projectPoints(points, cv2.Rodrigues(held.R)[0], held.t, held.K, None)
    source = cameras["00_03"]
    undistorted = cv2.undistortPoints(toolbox_project(points, source).reshape(-1, 1, 2), np.asarray(source["K"]),
                                      np.asarray(source["distCoef"]), P=np.asarray(source["K"]))
    assert np.abs(pinhole - undistorted).max() < 1e-4
    assert sorted(held.images) == [101, 103, 105] and held.union_masks == {}  # no masks: full frame only
    decoded = read_mp4(folder / "hdVideos" / "hd_00_03.mp4")[103]  # the video's HD frame 103
    expected = cv2.remap(decoded, *cv2.initUndistortRectifyMap(np.asarray(source["K"]), np.asarray(
        source["distCoef"]), None, np.asarray(source["K"]), (WIDTH, HEIGHT), cv2.CV_32FC1), cv2.INTER_LINEAR)
    got = np.asarray(Image.open(held.images[103])).astype(int)
    assert np.abs(got[10:-10, 10:-10] - expected[10:-10, 10:-10].astype(int)).mean() < 3
    for body_id in (0, 3):
        data = np.load(scene.humans[f"p{body_id}"].keypoints3d)
        assert str(data["layout"]) == "coco19" and data["frame_ids"].tolist() == [101, 102, 103, 104, 105]
        source_joints = np.stack([truth[(body_id, f)] for f in range(101, 106)])
        assert np.abs(data["joints"][..., :3] - source_joints[..., :3]).max() < 1e-9
        assert (data["joints"][:, 16, 3] == 0).all() and (data["joints"][:, 0, 3] == 0.8).all()


def test_stage02_fits_the_body_to_coco19_keypoints(imported, tmp_path):
    _, _, _, scene = imported
    run("01_sfm", scene, tmp_path)
    out = run("02_smpl_fit", scene, tmp_path)
    report = read_json(out / "humans" / "p0" / "fit_report.json")
    assert report["mode"] == "keypoints3d" and report["keypoints3d_residual_m"]["mean"] < 0.03


def test_bad_sources_get_one_message(imported, tmp_path):
    folder = imported[0]
    with pytest.raises(GlimpseError, match="no HD camera 00_07"):
        import_dataset("panoptic", folder, tmp_path / "s", ImportOptions(cameras=("7",)))
    with pytest.raises(GlimpseError, match="no calibration_"):
        import_dataset("panoptic", tmp_path, tmp_path / "s", ImportOptions())
    with pytest.raises(GlimpseError, match="among the chosen frames"):
        import_dataset("panoptic", folder, tmp_path / "s", ImportOptions(cameras=("16",), frames=parse_span("0:50")))
