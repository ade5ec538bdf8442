"""Camera paths for renders of finished runs: orbits about the people, COLMAP and JSON camera lists,
and how cameras and times pair into video frames (the render command itself: tests/test_joint.py)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from glimpse.body.config import BodyConfig, resolve_model_path
from glimpse.body.model import BodyModel
from glimpse.body.motion import BodySequence, builtin_motion
from glimpse.body.params import BodyParams
from glimpse.cameras.model import PinholeCamera
from glimpse.config import config_from_mapping, load_pipeline_yaml
from glimpse.errors import GlimpseError
from glimpse.io.cameras_json import write_cameras_json
from glimpse.io.colmap_text import write_colmap_text
from glimpse.replay.cameras import colmap_path, json_path, mean_up, orbit_path, turned
from glimpse.replay.motion import Z_UP_TO_Y_UP, retarget
from glimpse.replay.render import pair_shots_and_times

K = np.array([[100.0, 0.0, 63.5], [0.0, 100.0, 47.5], [0.0, 0.0, 1.0]])


def _looking_down_z(position) -> PinholeCamera:
    """A level OpenCV camera at ``position`` looking along +z (world y down, as a static scene's frame)."""
    return PinholeCamera(K.copy(), np.eye(3), -np.asarray(position, float), 128, 96)


def test_an_orbit_keeps_the_centre_in_place_and_circles_the_axis():
    start = _looking_down_z([0.3, -0.2, -4.0])
    centre, axis = np.array([0.0, 0.5, 2.0]), mean_up([start])
    assert np.allclose(axis, [0.0, -1.0, 0.0])  # y down: up is -y
    shots = orbit_path(start, centre, axis, 12)
    pixel, depth = start.project(centre[None])
    radius = np.linalg.norm((start.centre - centre)[[0, 2]])
    for shot in shots:
        here, here_depth = shot.project(centre[None])
        assert np.allclose(here, pixel) and np.allclose(here_depth, depth)  # the people stay where they were
        offset = shot.centre - centre
        assert np.isclose(np.linalg.norm(offset[[0, 2]]), radius) and np.isclose(offset[1], start.centre[1] - centre[1])
        assert np.allclose(shot.R @ shot.R.T, np.eye(3))
    assert np.allclose(shots[3].centre, turned(start, centre, axis, 90.0).centre)  # 30 degrees a frame
    back = turned(start, centre, axis, 360.0)
    assert np.allclose(back.R, start.R) and np.allclose(back.t, start.t)
    half = turned(start, centre, axis, 180.0)
    assert np.allclose(half.centre - centre, [-(start.centre - centre)[0], (start.centre - centre)[1],
                                              -(start.centre - centre)[2]])


def test_camera_lists_read_back_from_colmap_and_json(tmp_path):
    rng = np.random.default_rng(0)
    cameras = {}
    for fid in (0, 5, 9):
        q = rng.normal(size=4)
        w, x, y, z = q / np.linalg.norm(q)
        R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                      [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                      [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
        cameras[fid] = PinholeCamera(K.copy(), R, rng.normal(size=3), 128, 96)
    write_colmap_text(tmp_path / "colmap", 128, 96, cameras, ".png")
    write_cameras_json(tmp_path / "cameras.json", 128, 96, cameras)
    for shots in (colmap_path(tmp_path / "colmap"), json_path(tmp_path / "cameras.json")):
        assert [(s.width, s.height) for s in shots] == [(128, 96)] * 3
        for shot, fid in zip(shots, sorted(cameras)):
            assert np.allclose(shot.K, K) and np.allclose(shot.R, cameras[fid].R, atol=1e-9)
            assert np.allclose(shot.t, cameras[fid].t, atol=1e-9)
    with pytest.raises(GlimpseError, match="no COLMAP model"):
        colmap_path(tmp_path / "missing")


def test_one_camera_holds_still_one_time_freezes_and_otherwise_both_advance():
    a, b = (_looking_down_z([x, 0.0, -3.0]) for x in (0.0, 1.0))
    assert pair_shots_and_times([a], [3, 4, 5]) == [(a, 3), (a, 4), (a, 5)]
    assert pair_shots_and_times([a, b], [7]) == [(a, 7), (b, 7)]
    assert pair_shots_and_times([a, b], [1, 2]) == [(a, 1), (b, 2)]
    with pytest.raises(GlimpseError, match="2 cameras and 3 times"):
        pair_shots_and_times([a, b], [1, 2, 3])


def _standing(scale: float = 1.0) -> BodyParams:
    """A person in a static camera's frame (y down), upright, facing the camera (-z), 3 m ahead."""
    frames = 4
    return BodyParams(np.arange(frames), np.zeros(10), np.tile([np.pi, 0.0, 0.0], (frames, 1)),
                      np.zeros((frames, 69)), np.tile([0.2, 0.5, 3.0], (frames, 1)), scale, "free",
                      np.zeros(frames, bool))


def test_a_new_motion_starts_where_the_person_stands_and_heads_their_way():
    body_model = BodyModel.from_file(resolve_model_path(config_from_mapping(
        BodyConfig, load_pipeline_yaml()["body"], "body")))
    walk = builtin_motion("walk", 30, 30.0)  # forward (+z canonical) at 1.2 m/s
    for scale in (1.0, 2.0):
        person = _standing(scale)
        moved = retarget(walk, person, 2, body_model, np.arange(40))
        pelvis = lambda params, row: body_model(params.betas, params.global_orient[row:row + 1],  # noqa: E731
                                                params.body_pose[row:row + 1], params.transl[row:row + 1],
                                                scale=params.scale).joints[0, 0].double().numpy()
        start, there = pelvis(person, 2), pelvis(moved, 0)
        assert np.allclose(there[[0, 2]], start[[0, 2]], atol=1e-6)  # on the spot, on the ground (y down)
        assert abs(there[1] - start[1]) < 0.05 * scale
        step = pelvis(moved, 29) - there  # a second later: 1.2 m towards the camera (the person's forward, -z)
        assert np.isclose(step[2], -1.2 * 29 / 30 * scale, atol=0.02 * scale) and abs(step[0]) < 0.02 * scale
        assert np.allclose(moved.transl[29], moved.transl[39])  # the motion's last frame is held
        assert np.allclose(moved.body_pose[:30], walk.body_pose)  # the joints move as the motion says
    # the same motion stored z up (AMASS) lands identically
    stored = BodySequence(walk.betas, (Z_UP_TO_Y_UP.inv() * Rotation.from_rotvec(walk.global_orient)).as_rotvec(),
                          walk.body_pose, Z_UP_TO_Y_UP.inv().apply(walk.transl), walk.fps, "z", "test")
    z_up = retarget(stored, _standing(), 2, body_model, np.arange(30))
    y_up = retarget(walk, _standing(), 2, body_model, np.arange(30))
    assert np.allclose(z_up.transl, y_up.transl, atol=1e-6) and np.allclose(
        Rotation.from_rotvec(z_up.global_orient).as_matrix(), Rotation.from_rotvec(y_up.global_orient).as_matrix(),
        atol=1e-9)
    with pytest.raises(GlimpseError, match="no body at frame 9"):
        retarget(walk, _standing(), 9, body_model, np.arange(3))


def test_the_removal_video_tints_the_never_seen_background(tmp_path):
    from glimpse.eval.renders import NEVER_SEEN_TINT, with_never_seen
    from glimpse.io.images import write_png

    image = np.full((4, 6, 3), 100, np.uint8)
    mask = np.zeros((4, 6), bool)
    mask[1:3, 2:5] = True
    write_png(tmp_path / "000007.png", mask.astype(np.uint8) * 255)
    tinted = with_never_seen(image, tmp_path, 7)
    assert (tinted[~mask] == 100).all()
    expected = np.round(0.5 * 100 + 0.5 * np.array(NEVER_SEEN_TINT))
    assert (tinted[mask] == expected).all()
    assert (with_never_seen(image, tmp_path, 8) == image).all()  # no mask for that frame: unchanged
