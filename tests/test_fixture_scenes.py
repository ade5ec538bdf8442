"""Synthetic scenarios: valid scenes, deterministic, masks and keypoints consistent with the
rendered people, held-out views from other sides, the occluder and sparse cases as promised."""

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from glimpse.fixtures.scenes import SCENARIOS, make_scene
from glimpse.io.images import read_mask
from glimpse.scene import load_scene, read_keypoints2d, validate_scene


@pytest.fixture(scope="module")
def scenes(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("fixtures")
    return {name: make_scene(name, root / name, "tiny", seed=0) for name in SCENARIOS}


def facing(scene: Path, pid: str, frame: int) -> np.ndarray:
    """The person's facing direction (canonical +z) in the world at a frame."""
    body = np.load(scene.with_name(scene.name + ".groundtruth") / f"{pid}_body.npz")
    return Rotation.from_rotvec(body["global_orient"][frame]).apply([0.0, 0.0, 1.0])


def camera_centre(R, t) -> np.ndarray:
    return -np.asarray(R).T @ np.asarray(t)


def test_every_scenario_is_a_valid_scene(scenes):
    for name, scene in scenes.items():
        assert validate_scene(scene) == [], name
        loaded = load_scene(scene)
        assert loaded.humans and loaded.eval_cameras and loaded.cameras.poses
        assert (scene.with_name(scene.name + ".groundtruth") / "truth.json").is_file()


def test_the_same_seed_gives_identical_files(scenes, tmp_path):
    again = make_scene("demo", tmp_path / "demo", "tiny", seed=0)
    files = sorted(p.relative_to(scenes["demo"]) for p in scenes["demo"].rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(again) for p in again.rglob("*") if p.is_file())
    for rel in files:
        assert (scenes["demo"] / rel).read_bytes() == (again / rel).read_bytes(), rel


def test_masks_are_disjoint_and_confident_keypoints_land_on_their_person(scenes):
    for name, scene in scenes.items():
        loaded = load_scene(scene)
        for fid in loaded.frame_ids:
            masks = {pid: read_mask(h.masks[fid]) for pid, h in loaded.humans.items()}
            stacked = np.stack(list(masks.values()))
            assert stacked.sum(0).max() <= 1, (name, fid)  # one owner per pixel
        for pid, human in loaded.humans.items():
            kp = read_keypoints2d(human.keypoints2d)
            hits = total = 0
            for fid, points in zip(kp.frame_ids, kp.keypoints):
                mask = read_mask(human.masks[int(fid)])
                grown = np.zeros_like(mask)  # 2 px of slack for the keypoint noise
                ys, xs = np.nonzero(mask)
                for dy in range(-2, 3):
                    for dx in range(-2, 3):
                        grown[np.clip(ys + dy, 0, mask.shape[0] - 1), np.clip(xs + dx, 0, mask.shape[1] - 1)] = True
                for x, y, c in points:
                    if c >= 0.7:
                        total += 1
                        hits += bool(grown[int(round(y)), int(round(x))])
            assert total == 0 or hits / total > 0.9, (name, pid, hits, total)


def test_held_out_views_see_the_people_from_other_sides(scenes):
    scene = scenes["sparse"]
    loaded = load_scene(scene)
    fid = loaded.frame_ids[0]
    person = facing(scene, "p0", fid)
    pose = loaded.cameras.poses[fid]
    pelvis = np.load(scene / "humans" / "p0" / "smpl.npz")["transl"][0]
    to_input = camera_centre(pose.R, pose.t) - pelvis
    back = loaded.eval_cameras["cam00"]
    to_eval = camera_centre(back.R, back.t) - pelvis
    assert np.dot(person, to_input) > 0 > np.dot(person, to_eval)  # input sees the front, cam00 the back


def test_the_back_is_never_seen_in_the_sparse_scene(scenes):
    scene = scenes["sparse"]
    loaded = load_scene(scene)
    pelvis = np.load(scene / "humans" / "p0" / "smpl.npz")
    for k, fid in enumerate(loaded.frame_ids):
        pose = loaded.cameras.poses[fid]
        direction = camera_centre(pose.R, pose.t) - pelvis["transl"][k]
        assert np.dot(facing(scene, "p0", fid), direction) / np.linalg.norm(direction) > 0.3
    truth = json.loads((scene.with_name(scene.name + ".groundtruth") / "truth.json").read_text())
    assert len(truth["input_frames"]) <= 0.2 * 6 + 1  # about 10% of the frames (6 at tiny size)


def test_the_table_hides_the_legs_in_every_input_frame(scenes):
    loaded = load_scene(scenes["lower_body_occluded"])
    kp = read_keypoints2d(loaded.humans["p0"].keypoints2d)
    ankles_knees = kp.keypoints[:, [13, 14, 15, 16], 2]  # knees and ankles (COCO-17)
    shoulders = kp.keypoints[:, [5, 6], 2]
    assert (ankles_knees < 0.5).all()  # hidden (or dropped) in every frame
    # the upper body stays visible (at 64x48 a side-on shoulder may sit on the silhouette's edge)
    assert (shoulders[shoulders > 0] >= 0.7).mean() > 0.8


def test_a_motion_file_can_drive_a_person(tmp_path):
    """An AMASS-style (z-up) file: turned to y up, placed, standing on the floor."""
    import torch

    from glimpse.body.model import BodyModel
    from glimpse.fixtures.scenes import FREE_BODY, PersonSpec, place_motion

    frames = 30
    poses = np.zeros((frames, 156))
    poses[:, 0] = np.pi / 2  # AMASS bodies stand along +z: a quarter turn about x makes them upright
    poses[:, 3 + 2] = 0.3 * np.sin(np.linspace(0, 6, frames))  # a hip swinging
    np.savez(tmp_path / "clip.npz", poses=poses, trans=np.stack([np.linspace(0, 1, frames), np.zeros(frames),
                                                                 np.full(frames, 0.9)], 1),
             betas=np.zeros(16), mocap_framerate=np.array(30.0))
    model = BodyModel.from_file(FREE_BODY, dtype=torch.float64)
    params = place_motion(model, np.zeros(10), PersonSpec("neutral", str(tmp_path / "clip.npz"), (1.0, 2.0), 0.0),
                          12, 12.0)
    out = model(torch.zeros(12, 10, dtype=torch.float64), torch.as_tensor(params["global_orient"]),
                torch.as_tensor(params["body_pose"]), torch.as_tensor(params["transl"]))
    feet = out.vertices[:, :, 1].min(dim=1).values
    head = out.joints[:, 15, 1]
    assert torch.allclose(feet[0], torch.tensor(0.0, dtype=torch.float64), atol=1e-6)  # on the floor
    assert (head > 1.3).all()  # upright (y up)
