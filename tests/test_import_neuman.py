"""NeuMan import on a miniature copy of a sequence's layout (COLMAP text model with a SIMPLE_RADIAL camera and
an unregistered frame, segmentations with the person at 0, COCO-17 keypoint .npy files, joblib-written SMPL
lists indexed by frame number, per-frame similarity alignments with a scale that changes between frames), and
HUGS's copy (4d_humans/ with its npz and SAM masks): cameras, bodies, masks and NeuMan's split must agree with
the source, checked with smplx, OpenCV and COLMAP's own projection formula, not with the importer's code."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from PIL import Image
from scipy.spatial.transform import Rotation

from glimpse.errors import GlimpseError
from glimpse.importers import import_dataset
from glimpse.importers.common import ImportOptions
from glimpse.io.images import read_mask, read_rgb
from glimpse.scene import load_scene
from tests.body_files import write_random_smpl_pkl

joblib = pytest.importorskip("joblib")

WIDTH, HEIGHT, IMAGES = 64, 48, 13
UNREGISTERED = 7  # COLMAP did not register 00007.png
SCALES = {4: 2.2, 11: 1.9}  # frames whose alignment scale differs from the other frames' 2.0
F, CX, CY, K1 = 55.0, 32.3, 23.8, 0.04  # COLMAP SIMPLE_RADIAL (COLMAP's pixel centres)


def camera_pose(number: int) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera (R, t) of image ``number``, in COLMAP's units: a camera walking sideways, turning."""
    R = Rotation.from_euler("yx", [0.05 * number, 0.1]).as_matrix()
    centre = np.array([0.2 * number, -0.5, -8.0])
    return R, -R @ centre


def write_colmap_text(folder: Path, numbers: list[int], model: str, params: tuple[float, ...]) -> None:
    folder.mkdir(parents=True)
    (folder / "cameras.txt").write_text(f"# Camera list\n1 {model} {WIDTH} {HEIGHT} {' '.join(map(str, params))}\n")
    lines = ["# Image list"]
    for image_id, number in enumerate(numbers, start=1):
        R, t = camera_pose(number)
        qx, qy, qz, qw = Rotation.from_matrix(R).as_quat()
        pose = " ".join(f"{v:.17g}" for v in (qw, qx, qy, qz, *t))
        lines += [f"{image_id} {pose} 1 {number:05d}.png", ""]
    (folder / "images.txt").write_text("\n".join(lines) + "\n")
    (folder / "points3D.txt").write_text("# 3D point list\n1 0.1 0.2 3.0 128 128 128 0.5\n")


def write_sequence(folder: Path, rng: np.random.Generator, hugs: bool) -> dict:
    """bike/ in miniature (NeuMan's files, or HUGS's 4d_humans/ instead); returns the truth it was made from."""
    registered = [n for n in range(IMAGES) if n != UNREGISTERED]
    model, params = ("PINHOLE", (F, F, CX, CY)) if hugs else ("SIMPLE_RADIAL", (F, CX, CY, K1))
    write_colmap_text(folder / "sparse", registered, model, params)
    for sub in ("images", "segmentations", "keypoints", "4d_humans/sam_segmentations"):
        (folder / sub).mkdir(parents=True)
    truth: dict = {"masks": {}, "keypoints": {}, "model": model}
    for number in range(IMAGES):
        name = f"{number:05d}.png"
        Image.fromarray(rng.integers(0, 255, (HEIGHT, WIDTH, 3), np.uint8)).save(folder / "images" / name)
        person = np.zeros((HEIGHT, WIDTH), bool)
        person[5 + number % 4: 40, 20 + number: 35 + number] = True
        truth["masks"][number] = person
        if hugs:
            Image.fromarray((person * 255).astype(np.uint8)).save(folder / "4d_humans/sam_segmentations" / name)
        else:
            Image.fromarray(np.where(person, 0, 255).astype(np.uint8)).save(folder / "segmentations" / name)
            keypoints = np.concatenate([rng.uniform(0, 40, (17, 2)), rng.uniform(0, 1.2, (17, 1))], 1)
            np.save(folder / "keypoints" / f"{name}.npy", keypoints.astype(np.float32))
            truth["keypoints"][number] = keypoints
    betas = rng.normal(0, 0.5, 10).astype(np.float32)
    pose = [np.concatenate([rng.normal(0, 0.4, 3), rng.normal(0, 0.2, 69)]).astype(np.float32)
            for _ in range(IMAGES)]
    truth["betas"], truth["pose"] = betas.astype(np.float64), np.stack(pose).astype(np.float64)
    truth["similarity"] = {}
    for number in registered:
        R = Rotation.from_rotvec(rng.normal(0, 1.0, 3)).as_matrix()
        s = SCALES.get(number, 2.0)
        T = np.array([0.2 * number, 0.3, 1.0]) + rng.normal(0, 0.1, 3)
        truth["similarity"][number] = (R, s, T)
    if hugs:
        count = len(registered)
        similarity = [truth["similarity"][n] for n in registered]
        go = np.stack([(Rotation.from_matrix(R) * Rotation.from_rotvec(truth["pose"][n, :3])).as_rotvec()
                       for (R, _, _), n in zip(similarity, registered)])
        truth["pose"][registered, :3] = go  # HUGS's global_orient is already in the world
        for n, (R, s, T) in zip(registered, similarity):
            truth["similarity"][n] = (np.eye(3), s, T)
        np.savez(folder / "4d_humans/smpl_optimized_aligned_scale.npz", global_orient=go.astype(np.float32),
                 body_pose=truth["pose"][registered, 3:].astype(np.float32),
                 transl=np.stack([T for _, _, T in similarity]).astype(np.float32),
                 scale=np.array([s for _, s, _ in similarity], np.float32),
                 betas=np.tile(betas, (count, 1)))
    else:
        joblib.dump({1: {"pose": pose, "betas": [betas.copy() for _ in range(IMAGES)]}},
                    folder / "smpl_output_optimized.pkl")
        alignments = {}
        for number, (R, s, T) in truth["similarity"].items():
            M = np.concatenate([s * R, T[:, None]], axis=1)  # [s R | T], 3 x 4
            alignments[f"{number:05d}.png"] = M.T.astype(np.float32)
        np.save(folder / "alignments.npy", alignments, allow_pickle=True)
        truth["similarity"] = {n: (A.T[:, :3].astype(np.float64) / truth["similarity"][n][1],
                                   truth["similarity"][n][1], A.T[:, 3].astype(np.float64))
                               for n, A in ((int(k[:5]), v) for k, v in alignments.items())}
    return truth


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    root = tmp_path_factory.mktemp("neuman")
    model = write_random_smpl_pkl(root / "SMPL_NEUTRAL.pkl", seed=4, chumpy_style=False)
    scenes = {}
    for kind in ("neuman", "hugs"):
        truth = write_sequence(root / kind / "bike", np.random.default_rng(1), hugs=kind == "hugs")
        scene = import_dataset("neuman", root / kind, root / f"{kind}_scene",
                               ImportOptions(sequence="bike", body_models={"neutral": model}))
        scenes[kind] = (truth, load_scene(scene), root / kind / "bike")
    return model, scenes


def smplx_joints(model_path, betas, global_orient, body_pose, transl) -> np.ndarray:
    smplx = pytest.importorskip("smplx")
    count = len(global_orient)
    layer = smplx.SMPL(model_path=str(model_path), dtype=torch.float64, batch_size=count)
    as_tensor = lambda a: torch.as_tensor(np.asarray(a, np.float64))  # noqa: E731
    out = layer(betas=as_tensor(np.tile(betas, (count, 1))), global_orient=as_tensor(global_orient),
                body_pose=as_tensor(body_pose), transl=as_tensor(transl))
    return out.joints[:, :24].detach().numpy()


def colmap_pixels(points_camera: np.ndarray, model: str) -> np.ndarray:
    """COLMAP's own projection (src/colmap/sensor/models.h), minus its half-pixel offset."""
    x, y = points_camera[:, 0] / points_camera[:, 2], points_camera[:, 1] / points_camera[:, 2]
    radial = 1 + K1 * (x * x + y * y) if model == "SIMPLE_RADIAL" else 1.0
    return np.stack([F * x * radial + CX, F * y * radial + CY], axis=1) - 0.5


@pytest.mark.parametrize("kind", ["neuman", "hugs"])
def test_bodies_land_where_the_source_puts_them_seen_through_both_cameras(imported, kind):
    model, scenes = imported
    truth, scene, _ = scenes[kind]
    body = dict(np.load(scene.humans["p0"].smpl))
    numbers = body["frame_ids"].tolist()
    assert numbers == [0, 1, 2, 4, 5, 6, 8, 9, 11, 12]  # 3: test, 10: validation, 7: not registered
    ours = smplx_joints(model, body["betas"], body["global_orient"], body["body_pose"], body["transl"])
    unplaced = smplx_joints(model, truth["betas"], truth["pose"][numbers, :3], truth["pose"][numbers, 3:],
                            np.zeros((len(numbers), 3)))
    for row, number in enumerate(numbers):
        R, s, T = truth["similarity"][number]
        source = s * unplaced[row] @ R.T + T  # COLMAP's world
        Rc, tc = camera_pose(number)
        theirs_px = colmap_pixels(source @ Rc.T + tc, truth["model"])
        pose = scene.cameras.poses[number]
        ours_px, _ = cv2.projectPoints(ours[row], cv2.Rodrigues(pose.R)[0], pose.t, scene.cameras.K,
                                       scene.cameras.dist)
        error = np.abs(ours_px[:, 0] - theirs_px).max(axis=1)
        assert error[0] < 1e-6, (number, error[0])  # the pelvis, always (pixels)
        if number in SCALES:  # the rest of the body is (s / 2.0 - 1) off in size about the pelvis
            assert 0.01 < error.max() < 3.0
        else:
            # metres; smplx adds 1e-8 to every axis-angle it turns
            assert error.max() < 1e-6 and np.abs(ours[row] * 2.0 - source).max() < 1e-7
    assert scene.body_model == "smpl" and scene.overrides["body"]["model_path"] == str(model.resolve())


def test_frames_split_masks_keypoints_and_the_held_out_test_frames(imported):
    _, scenes = imported
    truth, scene, folder = scenes["neuman"]
    assert scene.frame_ids == [0, 1, 2, 4, 5, 6, 8, 9, 11, 12] and scene.camera_motion == "moving"
    assert np.allclose(scene.cameras.dist, [K1, 0, 0, 0]) and scene.fps == 3.0
    for number in (0, 12):
        assert np.array_equal(read_mask(scene.humans["p0"].masks[number]), truth["masks"][number])
        assert np.array_equal(read_rgb(scene.frame_paths[number]), read_rgb(folder / "images" / f"{number:05d}.png"))
    keypoints = dict(np.load(scene.humans["p0"].keypoints2d))
    assert str(keypoints["layout"]) == "coco17"
    expected = truth["keypoints"][5]
    assert np.allclose(keypoints["keypoints"][4, :, :2], expected[:, :2], atol=1e-5)
    assert np.allclose(keypoints["keypoints"][4, :, 2], np.clip(expected[:, 2], 0, 1), atol=1e-6)
    held = scene.eval_cameras["video_test"]
    assert sorted(held.images) == [3]  # NeuMan's test frames: the first half of every fifth registered image
    R, t = camera_pose(3)
    assert np.allclose(held.poses[3].R, R) and np.allclose(held.poses[3].t, t / 2.0)
    undistorted = cv2.undistort(np.asarray(truth["masks"][3], np.uint8), scene.cameras.K, scene.cameras.dist)
    assert np.mean(read_mask(held.union_masks[3]) != (undistorted > 0)) < 0.02
    hugs_truth, hugs_scene, _ = scenes["hugs"]
    assert hugs_scene.cameras.dist is None and "video_test" in hugs_scene.eval_cameras
    assert np.array_equal(read_mask(hugs_scene.humans["p0"].masks[8]), hugs_truth["masks"][8])
    assert hugs_scene.humans["p0"].keypoints2d is None  # HUGS's copy here has no keypoints/ files
    report = json.loads((scene.root / "neuman_import.json").read_text())
    assert report["colmap_units_per_metre"] == pytest.approx(2.0) and report["body_scale_relative"] == pytest.approx(
        {"min": 0.95, "max": 1.1}) and report["frames"] == {"input": 10, "test (held out)": 1,
                                                             "validation (left out)": 1}


def test_joblib_files_are_read_without_running_code(tmp_path):
    from glimpse.io.numpy_pickle import load_joblib_pickle

    class RunsCode:
        def __reduce__(self):
            return (print, ("this must not run",))

    data = {1: {"pose": [np.arange(72, dtype=np.float32)], "betas": np.asfortranarray(np.ones((2, 10)))}}
    for compress in (0, 3, ("gzip", 3), ("bz2", 3), ("lzma", 3), ("xz", 3)):
        joblib.dump(data, tmp_path / "ok.pkl", compress=compress)
        loaded = load_joblib_pickle(tmp_path / "ok.pkl")
        assert np.array_equal(loaded[1]["pose"][0], data[1]["pose"][0]) and np.array_equal(
            loaded[1]["betas"], data[1]["betas"])
    joblib.dump({"pose": np.zeros(3), "evil": RunsCode()}, tmp_path / "evil.pkl")
    with pytest.raises(GlimpseError, match="refusing to unpickle builtins.print"):
        load_joblib_pickle(tmp_path / "evil.pkl")
    joblib.dump(data, tmp_path / "ok.pkl")
    raw = (tmp_path / "ok.pkl").read_bytes()
    (tmp_path / "cut.pkl").write_bytes(raw[: len(raw) - 40])
    with pytest.raises(GlimpseError, match="cut.pkl: not a readable joblib file"):
        load_joblib_pickle(tmp_path / "cut.pkl")


def test_bad_sources_get_one_message(imported, tmp_path):
    model, scenes = imported
    options = ImportOptions(body_models={"neutral": model})
    with pytest.raises(GlimpseError, match="no sparse/ and images/"):
        import_dataset("neuman", tmp_path, tmp_path / "s", options)
    with pytest.raises(GlimpseError, match="--body-model"):
        import_dataset("neuman", scenes["neuman"][2], tmp_path / "s", ImportOptions())
    bare = tmp_path / "bare"
    (bare / "images").mkdir(parents=True)
    (bare / "sparse").mkdir()
    with pytest.raises(GlimpseError, match="no COLMAP model"):
        import_dataset("neuman", bare, tmp_path / "s", options)
    write_colmap_text(bare / "sparse2", [0, 1], "PINHOLE", (F, F, CX, CY))
    (bare / "sparse").rmdir()
    (bare / "sparse2").rename(bare / "sparse")
    with pytest.raises(GlimpseError, match="no bodies: give smpl_output_optimized.pkl"):
        import_dataset("neuman", bare, tmp_path / "s", options)
    assert not (tmp_path / "s").exists()
