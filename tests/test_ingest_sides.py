"""Left and right kept consistent along a track (glimpse.ingest.sides)."""

from __future__ import annotations

import numpy as np
import pytest

from glimpse.ingest.sides import (
    COCO17_EXCHANGE,
    exchange_legs,
    exchange_sides,
    legs_to_exchange,
    mirrored_3d,
    sides_to_exchange,
    torso_lengths,
)

KEEP = 0.1  # pipeline.yaml's ingest.sides_keep_weight
LEGS_KEEP, DISPUTE_SHARE = 0.5, 0.5  # pipeline.yaml's ingest.legs_keep_weight, legs_dispute_share

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


def _side_on_walker(frames: int, phase: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """([T, 17, 3] keypoints, [T] bool) of a person walking right, seen side-on by a static camera at 10 fps:
    hips 4 px a frame, each foot planted for 6 frames of a 10-frame stride and swinging 40 px in the other 4,
    half a stride apart (``phase``: where the feet are in their stride at frame 0, so that they pass each other
    between frames). The knees and ankles are named as a pose model with a habit names them: the front foot is
    always "left"; the bool marks the frames where that is wrong (the right foot in front)."""
    def foot(t: np.ndarray) -> np.ndarray:  # x of a foot whose stride starts at t = 0: planted, then swinging
        stride, within = np.divmod(t, 10.0)
        return 40.0 * stride + 40.0 * np.clip((within - 6.0) / 4.0, 0.0, 1.0)

    t = np.arange(frames) + phase
    left, right = foot(t), foot(t + 5.0) - 20.0
    track = np.zeros((frames, 17, 3))
    track[:, :, :2] = FRONT * [0.1, 1.0] + [300.0, 100.0]  # side-on: left and right a few pixels apart
    track[:, :, 0] += 4.0 * t[:, None]
    for (knee, ankle), x in (((13, 15), left), ((14, 16), right)):
        track[:, ankle, 0] = 300.0 + x + 10.0
        track[:, knee, 0] = (track[:, ankle, 0] + track[:, 11, 0]) / 2 + 5.0
    wrong = right > left
    track[wrong] = track[wrong][:, [*range(13), 14, 13, 16, 15]]
    track[:, :, 2] = 0.9
    return track, wrong


def test_legs_named_by_habit_are_renamed_by_the_planted_foot_where_the_mirrored_runs_dispute_them() -> None:
    keypoints, wrong = _side_on_walker(30)
    assert 5 < wrong.sum() < 25 and not np.diff(keypoints[:, 15, 0]).min() < -30  # no jump gives it away
    frames = np.arange(30)
    disputed = np.ones(30)  # every mirrored run named the front foot "right": the names are a guess throughout
    exchange = legs_to_exchange(frames, keypoints, disputed, LEGS_KEEP, DISPUTE_SHARE)
    assert np.array_equal(exchange, wrong)
    fixed, _ = exchange_legs(keypoints, np.zeros((30, 17, 4)), exchange)
    truth, _ = _side_on_walker(30)
    truth[wrong] = truth[wrong][:, [*range(13), 14, 13, 16, 15]]  # the walker as it is, named right
    np.testing.assert_array_equal(fixed, truth)
    # where the runs agree the names stand, guess or not; a frame disputed by fewer than half of them too
    assert not legs_to_exchange(frames, keypoints, np.zeros(30), LEGS_KEEP, DISPUTE_SHARE).any()
    assert not legs_to_exchange(frames, keypoints, np.full(30, 0.4), LEGS_KEEP, DISPUTE_SHARE).any()
    # a gap in the frame ids or a missing ankle links nothing across it: each side of it is decided on its own
    keypoints[10, 15, 2] = 0.0
    assert np.array_equal(legs_to_exchange(frames, keypoints, disputed, LEGS_KEEP, DISPUTE_SHARE)[11:], wrong[11:])


def test_legs_of_a_person_standing_still_keep_their_names() -> None:
    keypoints = np.repeat(_track(1, exchanged=[])[:1], 8, axis=0)
    assert not legs_to_exchange(np.arange(8), keypoints, np.ones(8), LEGS_KEEP, DISPUTE_SHARE).any()
    assert legs_to_exchange(np.arange(0), keypoints[:0], np.ones(0), LEGS_KEEP, DISPUTE_SHARE).shape == (0,)


def test_exchanging_legs_swaps_knees_and_ankles_only_in_the_frames_given() -> None:
    keypoints = _track(3, exchanged=[])
    relative3d = np.concatenate([np.random.default_rng(0).normal(size=(3, 17, 3)), np.ones((3, 17, 1))], 2)
    legs_2d, legs_3d = exchange_legs(keypoints, relative3d, np.array([False, True, False]))
    for values, out in ((keypoints, legs_2d), (relative3d, legs_3d)):
        np.testing.assert_array_equal(out[[0, 2]], values[[0, 2]])
        np.testing.assert_array_equal(out[1, :13], values[1, :13])
        np.testing.assert_array_equal(out[1, [13, 14, 15, 16]], values[1, [14, 13, 16, 15]])


def test_a_track_is_made_consistent_by_both_passes_and_its_legs_only_on_a_static_camera() -> None:
    from glimpse.ingest.config import load_ingest_config
    from glimpse.ingest.sides import consistent_sides

    config = load_ingest_config()
    keypoints, wrong = _side_on_walker(30)
    frames, disputed = np.arange(30), wrong.astype(float)  # the mirrored runs dispute the names where they are wrong
    relative3d = np.concatenate([np.random.default_rng(1).normal(size=(30, 17, 3)), np.ones((30, 17, 1))], 2)
    fixed, fixed_3d, sides, legs = consistent_sides(frames, keypoints, relative3d, disputed, True, 10.0, config)
    assert not sides.any() and np.array_equal(legs, wrong)
    expected, expected_3d = exchange_legs(keypoints, relative3d, wrong)
    np.testing.assert_array_equal(fixed, expected)
    np.testing.assert_array_equal(fixed_3d, expected_3d)
    moving = consistent_sides(frames, keypoints, relative3d, disputed, False, 10.0, config)
    assert not moving[3].any()
    np.testing.assert_array_equal(moving[0], keypoints)
    # a run of frames with every pair exchanged (a person facing the camera taken for one seen from behind)
    facing = _track(12, exchanged=[4, 5, 6])
    fixed, _, sides, legs = consistent_sides(np.arange(12), facing, np.zeros((12, 17, 4)), np.zeros(12), True, 10.0,
                                              config)
    assert np.flatnonzero(sides).tolist() == [4, 5, 6] and not legs.any()
    np.testing.assert_array_equal(fixed, _track(12, exchanged=[]))


def test_a_window_of_frames_names_the_legs_where_the_feet_pass_each_other_in_one_frame() -> None:
    keypoints, wrong = _side_on_walker(18)
    named, _ = exchange_legs(keypoints, np.zeros((18, 17, 4)), wrong)  # every frame named right
    # the swinging right foot passes the planted left one at frame 13, where the model puts both ankles on the
    # planted one's place and then names the front foot "left" from there to the track's end
    named[13, [13, 14, 15, 16]] = named[13, [13, 13, 15, 15]]
    named[13:] = named[13:][:, [*range(13), 14, 13, 16, 15]]
    disputed = (np.arange(18) >= 13).astype(float)  # the mirrored runs dispute those names; before, they agree
    frames = np.arange(18)
    # consecutive frames alone: frame 13 links nothing, and either naming of frames 13-17 costs the same
    assert not legs_to_exchange(frames, named, disputed, LEGS_KEEP, DISPUTE_SHARE, window=1).any()
    # over three frames, the left foot planted at frames 11 and 12 is the one named "right" after the crossing
    exchange = legs_to_exchange(frames, named, disputed, LEGS_KEEP, DISPUTE_SHARE, window=3)
    assert np.flatnonzero(exchange[:13]).size == 0 and exchange[14:].all()


def test_the_cheapest_histories_are_the_cheapest_labelling_of_all() -> None:
    """Against every one of the 2^T labellings: the cost of each frame's state plus that of every two frames up to
    the window apart."""
    import itertools

    from glimpse.ingest.sides import _cheapest_histories

    rng = np.random.default_rng(0)
    for count, window in ((1, 1), (6, 1), (7, 3), (9, 4)):
        unary, pairs = rng.random((count, 2)), rng.random((count, window, 2, 2))

        def cost(states: tuple[int, ...]) -> float:
            return sum(unary[t, states[t]] + sum(pairs[t, d - 1, states[t - d], states[t]]
                                                 for d in range(1, min(window, t) + 1)) for t in range(count))

        best = min(cost(states) for states in itertools.product((0, 1), repeat=count))
        found = tuple(int(s) for s in _cheapest_histories(unary, pairs))
        assert cost(found) == pytest.approx(best)
