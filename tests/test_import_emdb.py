"""EMDB import on a miniature copy of a sequence's layout (images/<5 digits>.jpg, the sequence pickle with a
gender, per-frame world-to-camera extrinsics and smplx-style SMPL, good_frames_mask): cameras and bodies must
agree with the source; the person's gendered model is asked for by name."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from PIL import Image

from glimpse.errors import GlimpseError
from glimpse.importers import import_dataset
from glimpse.importers.common import ImportOptions, parse_body_models, parse_span
from glimpse.scene import load_scene
from tests.body_files import write_random_smpl_pkl

WIDTH, HEIGHT, FRAMES = 48, 64, 6  # a portrait phone video


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    root = tmp_path_factory.mktemp("emdb")
    folder = root / "P0" / "09_outdoor_walk"
    (folder / "images").mkdir(parents=True)
    rng = np.random.default_rng(0)
    for f in range(FRAMES):
        Image.fromarray(rng.integers(0, 255, (HEIGHT, WIDTH, 3), np.uint8)).save(folder / "images" / f"{f:05d}.jpg")
    extrinsics = np.tile(np.eye(4, dtype=np.float32), (FRAMES, 1, 1))
    for f in range(FRAMES):
        angle = 0.1 * f
        extrinsics[f, :3, :3] = [[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]]
        extrinsics[f, :3, 3] = [0.1 * f, 0.2, 3.0]
    good = np.ones(FRAMES, bool)
    good[2] = False
    data = {"gender": "male", "name": "P0_09_outdoor_walk", "emdb1": False, "emdb2": True, "n_frames": FRAMES,
            "good_frames_mask": good,
            "camera": {"intrinsics": np.array([[60.0, 0, 24.0], [0, 60.0, 32.0], [0, 0, 1]], np.float32),
                       "extrinsics": extrinsics, "width": WIDTH, "height": HEIGHT},
            "smpl": {"poses_root": rng.normal(0, 0.3, (FRAMES, 3)).astype(np.float32),
                     "poses_body": rng.normal(0, 0.2, (FRAMES, 69)).astype(np.float32),
                     "trans": rng.normal(0, 0.5, (FRAMES, 3)).astype(np.float32),
                     "betas": rng.normal(0, 1, 10).astype(np.float32)},
            "kp2d": np.zeros((FRAMES, 24, 2), np.float32), "bboxes": {"bboxes": np.zeros((FRAMES, 4), np.float32),
                                                                     "invalid_idxs": np.array([2])}}
    with (folder / "P0_09_outdoor_walk_data.pkl").open("wb") as handle:
        pickle.dump(data, handle)
    male = write_random_smpl_pkl(root / "SMPL_MALE.pkl", seed=5, chumpy_style=False)
    return root, data, male


def test_cameras_and_bodies_are_the_sources_and_bad_frames_have_no_body(source, tmp_path):
    root, data, male = source
    scene = load_scene(import_dataset("emdb", root, tmp_path / "scene", ImportOptions(
        sequence="P0/09_outdoor_walk", frames=parse_span("1:6"), body_models=parse_body_models([f"male={male}"]))))
    assert scene.frame_ids == [1, 2, 3, 4, 5] and scene.camera_motion == "moving" and not scene.eval_cameras
    for f in scene.frame_ids:
        pose = scene.cameras.poses[f]
        assert np.allclose(pose.R, data["camera"]["extrinsics"][f, :3, :3]) and np.allclose(
            pose.t, data["camera"]["extrinsics"][f, :3, 3])
    assert np.allclose(scene.cameras.K, data["camera"]["intrinsics"]) and scene.cameras.dist is None
    body = np.load(scene.humans["p0"].smpl)
    assert body["frame_ids"].tolist() == [1, 3, 4, 5]  # frame 2 is not a good frame
    rows = [1, 3, 4, 5]
    for key, source_key in (("global_orient", "poses_root"), ("body_pose", "poses_body"), ("transl", "trans")):
        assert np.array_equal(body[key], data["smpl"][source_key][rows].astype(np.float64))
    assert scene.body_model == "smpl" and scene.overrides["body"]["model_path"] == str(male.resolve())


def test_the_persons_gendered_model_is_asked_for(source, tmp_path):
    root, _, male = source
    with pytest.raises(GlimpseError, match="SMPL's male model; give it with --body-model male=/path/to/SMPL_MALE"):
        import_dataset("emdb", root, tmp_path / "s", ImportOptions(sequence="P0_09_outdoor_walk",
                                                                   body_models={"neutral": male}))
    with pytest.raises(GlimpseError, match="GENDER one of neutral, male, female"):
        parse_body_models(["man=/x.pkl"])
    with pytest.raises(GlimpseError, match="no <subject>_<sequence>_data.pkl"):
        import_dataset("emdb", tmp_path, tmp_path / "s", ImportOptions())
    assert not (tmp_path / "s").exists()
