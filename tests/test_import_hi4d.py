"""Hi4D import on a miniature copy of a sequence's layout (meta.npz with start, end and genders, the 8-camera
rgb_cameras.npz with distortion and a skew term, images/<camera>/<frame:06d>.jpg from frame 9, per-person masks
with 0/255 values, smpl/<frame>.npz for both people): cameras, bodies and masks must agree with the source; a
pair of a man and a woman gets each person's SMPL model, and the pipeline's first stages run on it."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from PIL import Image

from glimpse.errors import GlimpseError
from glimpse.importers import import_dataset
from glimpse.importers.common import ImportOptions, parse_span
from glimpse.io.images import read_mask
from glimpse.scene import load_scene
from tests.body_files import write_random_smpl_pkl

WIDTH, HEIGHT = 47, 64  # portrait, as Hi4D's 940 x 1280
CAMERA_IDS = (4, 76, 88)
START, END = 9, 14


def write_sequence(folder, genders, rng):
    folder.mkdir(parents=True)
    np.savez(folder / "meta.npz", start=np.array(START), end=np.array(END), num_persons=np.array(2),
             genders=np.array(genders), betas=rng.normal(0, 1, (2, 10)), contact_ids=np.array([10, 11]),
             mono_cam=np.array(76))
    intrinsics, extrinsics = [], []
    for k, _ in enumerate(CAMERA_IDS):
        angle = 0.9 * (k - 1)
        R = cv2.Rodrigues(np.array([0.0, angle, 0.0]))[0]
        intrinsics.append([[60.0 + k, 0.3, 23.1], [0, 61.0, 32.2], [0, 0, 1]])
        extrinsics.append(np.concatenate([R, np.array([[0.1 * k], [0.2], [3.0]])], axis=1))
    dist = np.array([[-0.1, 0.02, 0.001, 0.0, 0.0]] * len(CAMERA_IDS))
    (folder / "cameras").mkdir()
    np.savez(folder / "cameras" / "rgb_cameras.npz", ids=np.array(CAMERA_IDS), intrinsics=np.array(intrinsics),
             extrinsics=np.array(extrinsics), dist_coeffs=dist)
    (folder / "smpl").mkdir()
    truth = {}
    for frame in range(START, END + 1):
        entry = {"betas": np.tile(rng.normal(0, 1, (1, 10)), (2, 1)), "global_orient": rng.normal(0, 0.3, (2, 3)),
                 "body_pose": rng.normal(0, 0.2, (2, 69)), "transl": rng.normal(0, 0.5, (2, 3)),
                 "joints_3d": np.zeros((2, 24, 3)), "contact": np.zeros((2, 10))}
        np.savez(folder / "smpl" / f"{frame:06d}.npz", **entry)
        truth[frame] = entry
        for camera in CAMERA_IDS:
            (folder / "images" / str(camera)).mkdir(parents=True, exist_ok=True)
            Image.fromarray(rng.integers(0, 255, (HEIGHT, WIDTH, 3), np.uint8)).save(
                folder / "images" / str(camera) / f"{frame:06d}.jpg", quality=95)
            for person in range(2):
                mask = np.zeros((HEIGHT, WIDTH), np.uint8)
                mask[10 + 5 * person: 50, 5 + 20 * person: 25 + 20 * person] = 255
                path = folder / "seg" / "img_seg_mask" / str(camera) / str(person) / f"{frame:06d}.png"
                path.parent.mkdir(parents=True, exist_ok=True)
                Image.fromarray(mask).save(path)
    return truth


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    root = tmp_path_factory.mktemp("hi4d")
    rng = np.random.default_rng(0)
    truth = write_sequence(root / "pair00" / "dance00", ["female", "female"], rng)
    write_sequence(root / "pair01" / "hug01", ["male", "female"], rng)
    female = write_random_smpl_pkl(root / "SMPL_FEMALE.pkl", seed=2, chumpy_style=False)
    scene = import_dataset("hi4d", root, root / "scene", ImportOptions(
        sequence="pair00/dance00", frames=parse_span("10:14"), eval_every=2, body_models={"female": female}))
    return root, truth, female, load_scene(scene)


def test_cameras_bodies_and_masks_agree_with_the_source(imported):
    root, truth, female, scene = imported
    assert scene.frame_ids == [10, 11, 12, 13] and set(scene.humans) == {"p0", "p1"}
    assert sorted(scene.eval_cameras) == ["cam4", "cam88"]  # camera 76 is the input (GTU's)
    cameras = np.load(root / "pair00" / "dance00" / "cameras" / "rgb_cameras.npz")
    index = list(cameras["ids"]).index(76)
    K = cameras["intrinsics"][index].copy()
    assert scene.cameras.K[0, 1] == 0.0 and np.allclose(scene.cameras.K[[0, 1], 2], K[[0, 1], 2])
    points = np.array([[0.1, 0.2, 0.1], [-0.3, -0.1, 0.4]])
    pose = scene.cameras.poses[12]
    K[0, 1] = 0.0  # the skew the importer drops (0.3 px over 60 px focal)
    ours, _ = cv2.projectPoints(points, cv2.Rodrigues(pose.R)[0], pose.t, scene.cameras.K, scene.cameras.dist)
    theirs, _ = cv2.projectPoints(points, cv2.Rodrigues(cameras["extrinsics"][index][:, :3])[0],
                                  cameras["extrinsics"][index][:, 3], K, cameras["dist_coeffs"][index])
    assert np.abs(ours - theirs).max() < 1e-9
    for person in (0, 1):
        body = np.load(scene.humans[f"p{person}"].smpl)
        assert body["frame_ids"].tolist() == [10, 11, 12, 13]
        for key in ("global_orient", "body_pose", "transl"):
            assert np.array_equal(body[key], np.stack([truth[f][key][person] for f in range(10, 14)]))
        source = np.asarray(Image.open(root / "pair00" / "dance00" / "seg" / "img_seg_mask" / "76" / str(person) /
                                       "000011.png")) != 0
        assert np.array_equal(read_mask(scene.humans[f"p{person}"].masks[11]), source)
    held = scene.eval_cameras["cam4"]
    assert sorted(held.images) == [10, 12] and set(held.person_masks) == {"p0", "p1"}
    assert scene.overrides["body"]["model_path"] == str(female.resolve())


def test_a_man_and_a_woman_each_get_their_own_smpl_model(imported, tmp_path):
    import pickle

    from tests.body_files import random_smpl_arrays
    from tests.stage_helpers import read_json, run

    root, _, female, _ = imported
    with pytest.raises(GlimpseError, match=r"person 0 \(male\) are parameters of SMPL's male model; give it with "
                                           r"--body-model male="):
        import_dataset("hi4d", root, tmp_path / "s", ImportOptions(sequence="pair01/hug01",
                                                                   body_models={"female": female}))
    arrays = random_smpl_arrays(5)  # a male model sharing the female one's topology, as SMPL's do
    with open(female, "rb") as handle:
        arrays["f"] = pickle.load(handle)["f"]
    male = tmp_path / "SMPL_MALE.pkl"
    with open(male, "wb") as handle:
        pickle.dump(arrays, handle, protocol=2)
    scene = load_scene(import_dataset("hi4d", root, tmp_path / "mixed", ImportOptions(
        sequence="pair01/hug01", frames=parse_span("10:12"), body_models={"female": female, "male": male})))
    assert scene.overrides["body"] == {"model_path": str(male.resolve()),
                                       "person_model_paths": [f"p1={female.resolve()}"]}
    run("01_sfm", scene.root, tmp_path / "out")
    out = run("02_smpl_fit", scene.root, tmp_path / "out")  # each person posed by their own model in the overlay
    recorded = read_json(out.parent / ".params" / "02_smpl_fit.json")["params"]["body"]
    assert recorded["person_model_paths"] == [f"p1={female.resolve()}"] and (out / "overlay.mp4").is_file()


def test_an_unknown_camera_is_refused(imported, tmp_path):
    root, _, female, _ = imported
    with pytest.raises(GlimpseError, match="no camera 5"):
        import_dataset("hi4d", root / "pair00" / "dance00", tmp_path / "s",
                       ImportOptions(cameras=("5",), body_models={"female": female}))
