"""glimpse.scene writes what it reads: a scene written part by part loads back with the same values, and a
scene that breaks the format is refused before it replaces anything."""

from __future__ import annotations

import numpy as np
import pytest

from glimpse.errors import SceneError
from glimpse.io.images import read_mask, read_rgb
from glimpse.scene import CameraPose, load_scene, read_keypoints2d, read_keypoints3d
from glimpse.scene.writer import SceneWriter

WIDTH, HEIGHT, FRAMES = 24, 16, 3


def rotation_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_a_written_scene_reads_back_the_same(tmp_path):
    rng = np.random.default_rng(0)
    K = np.array([[30.0, 0.0, (WIDTH - 1) / 2], [0.0, 31.0, (HEIGHT - 1) / 2], [0.0, 0.0, 1.0]])
    poses = {i: CameraPose(rotation_z(0.1 * i), np.array([0.1 * i, 0.0, 2.0])) for i in range(FRAMES)}
    frames = {i: rng.integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8) for i in range(FRAMES)}
    masks = {i: rng.random((HEIGHT, WIDTH)) > 0.5 for i in range(FRAMES)}
    ids = np.arange(FRAMES)
    keypoints = np.concatenate([rng.uniform(0, 16, (FRAMES, 17, 2)), rng.uniform(0, 1, (FRAMES, 17, 1))], axis=2)
    joints = np.concatenate([rng.normal(0, 1, (FRAMES, 17, 3)), np.ones((FRAMES, 17, 1))], axis=2)
    smpl = dict(betas=rng.normal(0, 1, 10), global_orient=rng.normal(0, 0.3, (FRAMES, 3)),
                body_pose=rng.normal(0, 0.3, (FRAMES, 69)), transl=rng.normal(0, 1, (FRAMES, 3)))

    writer = SceneWriter(tmp_path / "scene", "written", 25.0, "moving", "free",
                         overrides={"04_bg_pretrain": {"iterations": 5}})
    for i in range(FRAMES):
        writer.frame(i, frames[i])
        writer.person_mask("alice", i, masks[i])
    writer.input_cameras(WIDTH, HEIGHT, K, np.array([0.01, 0.0, 0.0, 0.0]), poses)
    writer.smpl("alice", ids, **smpl)
    relative3d = np.concatenate([rng.normal(0, 0.4, (FRAMES, 17, 3)), rng.uniform(0, 1, (FRAMES, 17, 1))], axis=2)
    writer.keypoints2d("alice", ids, "coco17", keypoints, relative3d)
    writer.keypoints3d("alice", ids, "coco17", joints)
    writer.reference("alice", "front", frames[0])
    writer.eval_camera("cam0", WIDTH, HEIGHT, K, poses[1].R, poses[1].t)
    writer.eval_view("cam0", 0, frames[2], masks[0], {"alice": masks[0]})
    root = writer.finish()

    scene = load_scene(root)
    assert (scene.name, scene.fps, scene.camera_motion, scene.body_model) == ("written", 25.0, "moving", "free")
    assert scene.overrides == {"04_bg_pretrain": {"iterations": 5}}
    assert all(np.array_equal(read_rgb(scene.frame_paths[i]), frames[i]) for i in range(FRAMES))
    cameras = scene.cameras
    assert (cameras.width, cameras.height) == (WIDTH, HEIGHT) and np.allclose(cameras.K, K)
    assert np.allclose(cameras.dist, [0.01, 0.0, 0.0, 0.0])
    assert all(np.allclose(cameras.poses[i].R, poses[i].R) and np.allclose(cameras.poses[i].t, poses[i].t)
               for i in range(FRAMES))
    person = scene.humans["alice"]
    assert all(np.array_equal(read_mask(person.masks[i]), masks[i]) for i in range(FRAMES))
    assert np.allclose(read_keypoints2d(person.keypoints2d).keypoints, keypoints)
    assert np.allclose(read_keypoints2d(person.keypoints2d).relative3d, relative3d)
    assert np.allclose(read_keypoints3d(person.keypoints3d).joints, joints)
    with np.load(person.smpl) as archive:
        assert all(np.allclose(archive[key], value) for key, value in smpl.items())
    held_out = scene.eval_cameras["cam0"]
    assert np.allclose(held_out.camera_at(0).R, poses[1].R)
    assert np.array_equal(read_rgb(held_out.images[0]), frames[2])
    assert np.array_equal(read_mask(held_out.person_masks["alice"][0]), masks[0])
    assert not root.with_name("scene.tmp").exists()


def test_a_broken_scene_is_refused_and_the_previous_one_kept(tmp_path):
    good = SceneWriter(tmp_path / "scene", "first", 10.0, "static")
    good.frame(0, np.zeros((HEIGHT, WIDTH, 3), np.uint8))
    good.finish()
    broken = SceneWriter(tmp_path / "scene", "second", 10.0, "static")
    broken.frame(0, np.zeros((HEIGHT, WIDTH, 3), np.uint8))
    broken.keypoints2d("bob", np.array([5]), "coco17", np.zeros((1, 17, 3)))  # a frame the scene does not have
    with pytest.raises(SceneError, match="keypoints2d.npz"):
        broken.finish()
    assert load_scene(tmp_path / "scene").name == "first"
    assert (tmp_path / "scene.tmp" / "scene.yaml").is_file()  # kept for inspection


def _one_frame_scene(root, value: int):
    writer = SceneWriter(root, "linked", 25.0, "static", "free")
    writer.frame(0, np.full((HEIGHT, WIDTH, 3), value, np.uint8))
    writer.person_mask("alice", 0, np.ones((HEIGHT, WIDTH), bool))
    writer.keypoints2d("alice", np.arange(1), "coco17", np.ones((1, 17, 3)))
    return writer.finish()


def test_a_scene_path_that_links_to_a_folder_is_written_through_the_link(tmp_path):
    """A scene folder kept on another disk behind a link: the scene replaces the folder's content, the link stays."""
    target = tmp_path / "disk" / "scene"
    _one_frame_scene(target, 10)
    link = tmp_path / "scene"
    link.symlink_to(target, target_is_directory=True)
    assert _one_frame_scene(link, 200) == target.resolve()
    assert link.is_symlink() and not (tmp_path / "scene.tmp").exists()
    assert read_rgb(load_scene(link).frame_paths[0])[0, 0, 0] == 200


def test_a_scene_path_that_is_a_file_is_refused_before_anything_is_written(tmp_path):
    from glimpse.errors import GlimpseError

    for path in (tmp_path / "notes.txt", tmp_path / "link_to_notes"):
        (tmp_path / "notes.txt").write_text("keep me")
        if path.name == "link_to_notes":
            path.symlink_to(tmp_path / "notes.txt")
        with pytest.raises(GlimpseError, match=f"{path.name}: exists and is not a folder"):
            SceneWriter(path, "refused", 25.0)
        assert (tmp_path / "notes.txt").read_text() == "keep me"
        assert not path.with_name(path.name + ".tmp").exists()
