"""Left and right kept consistent along a track (glimpse.ingest.sides)."""

from __future__ import annotations

import numpy as np

from glimpse.ingest.sides import COCO17_EXCHANGE, exchange_sides, mirrored_3d, sides_to_exchange, torso_lengths

KEEP = 0.1  # pipeline.yaml's ingest.sides_keep_weight

# COCO-17 of an upright person facing the camera, image pixels (y down), torso 100 px: their left on the image's right
FRONT = np.array([
    [0, -160], [8, -168], [-8, -168], [16, -164], [-16, -164],  # nose, eyes, ears
    [40, -100], [-40, -100], [50, -50], [-50, -50], [55, 0], [-55, 0],  # shoulders, elbows, wrists
    [20, 0], [-20, 0], [22, 80], [-22, 80], [24, 160], [-24, 160],  # hips, knees, ankles
], float)


def _track(frames: int, exchanged: list[int]) -> np.ndarray:
    """[T, 17, 3] a person facing the camera, walking right 3 px a frame, wrists swinging; the frames
    ``exchanged`` with every left/right pair swapped, as a pose model may give them."""
    track = np.zeros((frames, 17, 3))
    for t in range(frames):
        points = FRONT + [300 + 3 * t, 300]
        points[9:11, 1] += 6 * np.sin(t)
        track[t, :, :2] = points[COCO17_EXCHANGE] if t in exchanged else points
        track[t, :, 2] = 0.9
    return track


def _turning(frames: int) -> np.ndarray:
    """[T, 17, 3] a person turning half round about the vertical over the track (front, side-on, back): the
    labels never jump, each joint moves continuously."""
    track = np.zeros((frames, 17, 3))
    for t in range(frames):
        squeeze = np.cos(np.pi * t / (frames - 1))  # 1 (front) -> -1 (back): x mirrored about the centre line
        track[t, :, :2] = FRONT * [squeeze, 1.0] + [300, 300]
        track[t, :, 2] = 0.9
    return track


def test_the_shorter_runs_between_jumps_are_exchanged() -> None:
    assert np.flatnonzero(sides_to_exchange(_track(12, exchanged=[4, 5, 6]), KEEP)).tolist() == [4, 5, 6]
    assert np.flatnonzero(sides_to_exchange(_track(12, exchanged=[0, 1, 11]), KEEP)).tolist() == [0, 1, 11]
    # the longer run wins: frames 0-6 exchanged is the model's labels for 7 of 12 frames
    assert np.flatnonzero(sides_to_exchange(_track(12, exchanged=list(range(7))), KEEP)).tolist() == [7, 8, 9, 10, 11]


def test_a_consistent_track_and_a_person_turning_round_are_left_as_they_are() -> None:
    assert not sides_to_exchange(_track(10, exchanged=list(range(10))), KEEP).any()
    assert not sides_to_exchange(_turning(15), KEEP).any()
    assert sides_to_exchange(np.zeros((0, 17, 3)), KEEP).shape == (0,)


def test_frames_missing_joints_are_linked_by_the_pairs_both_frames_hold() -> None:
    track = _track(10, exchanged=[5, 6])
    track[4, [7, 8, 9, 10, 13, 14, 15, 16], 2] = 0.0  # arms and legs missing the frame before the run
    track[6, :5, 2] = 0.0  # the head missing inside it
    assert np.flatnonzero(sides_to_exchange(track, KEEP)).tolist() == [5, 6]
    track[3, 5, 2] = 0.0  # no shoulder: no torso length in that frame, the track's median stands in
    assert np.isnan(torso_lengths(track)[3]) and torso_lengths(track)[0] == 100.0
    assert np.flatnonzero(sides_to_exchange(track, KEEP)).tolist() == [5, 6]


def _body_3d(facing_camera: bool) -> np.ndarray:
    """[1, 17, 4] metric landmarks (image axes: x right, y down, z away) of a body facing the camera or away,
    labelled correctly, confidence 1."""
    points = np.zeros((17, 3))
    points[:, :2] = FRONT / 100 * 0.5  # 0.5 m torso
    points[0, 2] = -0.12  # the nose in front of the face
    if not facing_camera:  # turned half a turn about the vertical: x and z change sign
        points[:, [0, 2]] *= -1
    return np.concatenate([points, np.ones((17, 1))], 1)[None]


def test_exchanging_sides_swaps_the_pairs_and_mirrors_the_depth_of_a_skeleton_it_made_a_mirror_image() -> None:
    keypoints = _track(1, exchanged=[0])
    away = _body_3d(facing_camera=False)  # what the model says of a person facing the camera: "seen from behind"
    assert not mirrored_3d(away).any() and not mirrored_3d(_body_3d(True)).any()
    fixed_2d, fixed_3d = exchange_sides(keypoints, away, np.array([True]))
    assert np.array_equal(fixed_2d[0], _track(1, [])[0])
    # labels exchanged alone would leave a mirror image (left on the right, nose behind); the depth is mirrored too
    assert np.allclose(fixed_3d, _body_3d(facing_camera=True))
    # a skeleton whose 3D was right while its labels were exchanged keeps its depth
    mirror_image = _body_3d(facing_camera=True)[:, COCO17_EXCHANGE]
    assert mirrored_3d(mirror_image).all()
    assert np.allclose(exchange_sides(keypoints, mirror_image, np.array([True]))[1], _body_3d(facing_camera=True))
    untouched_2d, untouched_3d = exchange_sides(keypoints, away, np.array([False]))
    assert np.array_equal(untouched_2d, keypoints) and np.array_equal(untouched_3d, away)
    missing_nose = away.copy()
    missing_nose[0, 0, 3] = 0.0
    assert not mirrored_3d(missing_nose).any()
