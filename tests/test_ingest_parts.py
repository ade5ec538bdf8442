"""The ingest's pure parts: regions and crops, BlazePose's decoding (anchors, boxes, suppression, heatmap
refinement, mirroring), appearance, the frame-time grid and the evaluation against ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from glimpse.ingest.appearance import appearance, appearance_distance
from glimpse.ingest.blazepose import (
    DETECTOR_SIZE,
    LANDMARK_COUNT,
    LANDMARK_SIZE,
    LANDMARK_VALUES,
    Detections,
    decode_detections,
    mirror_permutation,
    refine_with_heatmap,
    ssd_anchor_centres,
    unmirror,
    weighted_nms,
)
from glimpse.ingest.crop import (
    Region,
    crop_affine,
    crop_image,
    crop_to_image,
    outside_image,
    paste_to_image,
    region_around_box,
    region_from_alignment,
)
from glimpse.ingest.evaluate import FoundPerson, TruePerson, score_people
from glimpse.ingest.survey import grid_choice

# --- regions and crops ---------------------------------------------------------------------------------------

def test_upright_alignment_gives_no_rotation_and_twice_the_radius() -> None:
    region = region_from_alignment(np.array([100.0, 200.0]), np.array([100.0, 120.0]), grow=1.25)
    assert region.angle == pytest.approx(0.0)
    assert region.side == pytest.approx(2 * 80 * 1.25)
    np.testing.assert_allclose(region.centre, [100, 200])


def test_rotated_region_puts_the_scale_point_at_the_top_of_the_crop() -> None:
    centre, scale_point = np.array([50.0, 60.0]), np.array([90.0, 60.0])  # lying, head to the right
    region = region_from_alignment(centre, scale_point, grow=1.0)
    size = 64
    affine = crop_affine(region, size)
    # the crop pixel at the top middle edge maps to the scale point (side = 2 * radius)
    top_middle = np.array([[size / 2 - 0.5, -0.5]])
    np.testing.assert_allclose(crop_to_image(region, top_middle, size), scale_point[None], atol=1e-9)
    np.testing.assert_allclose(affine[:, :2] @ [size / 2 - 0.5, size / 2 - 0.5] + affine[:, 2], centre, atol=1e-9)


def test_crop_and_paste_are_inverse_maps() -> None:
    image = np.zeros((60, 80), np.float32)
    image[20:30, 35:45] = 1.0
    region = Region(np.array([40.0, 25.0]), 40.0, 0.3)
    crop = crop_image(image[..., None].repeat(3, 2), region, 40)[..., 0]
    back = paste_to_image(crop, region, 80, 60)
    assert np.abs(back[22:28, 37:43] - 1.0).max() < 0.05  # the square's interior survives the round trip
    assert back[:10].max() == 0.0  # outside the region: zero


def test_region_around_box_is_an_upright_square_on_the_longer_side() -> None:
    region = region_around_box(np.array([10.0, 20.0, 30.0, 100.0]), 1.5)
    assert region.angle == 0.0 and region.side == pytest.approx(120.0)
    np.testing.assert_allclose(region.box(), [-40, 0, 80, 120])



def test_outside_image_follows_the_pixel_centre_convention() -> None:
    # a 4 x 3 image's pixels cover -0.5 .. 3.5 across and -0.5 .. 2.5 down
    points = np.array([[-0.5, 0.0], [-0.51, 0.0], [3.5, 2.5], [3.51, 1.0], [1.0, 2.51], [1.0, -0.6]])
    assert outside_image(points, (3, 4)).tolist() == [False, True, False, True, True, True]

# --- BlazePose decoding --------------------------------------------------------------------------------------

def test_anchor_layout_matches_the_detector_output() -> None:
    anchors = ssd_anchor_centres()
    assert anchors.shape == (2254, 2)  # 28*28*2 + 14*14*2 + 7*7*6
    np.testing.assert_allclose(anchors[0], [0.5 / 28, 0.5 / 28])
    np.testing.assert_allclose(anchors[1], anchors[0])  # two anchors per cell
    np.testing.assert_allclose(anchors[2], [1.5 / 28, 0.5 / 28])  # x runs fastest
    np.testing.assert_allclose(anchors[28 * 28 * 2], [0.5 / 14, 0.5 / 14])
    np.testing.assert_allclose(anchors[-1], [6.5 / 7, 6.5 / 7])
    assert (anchors[-6:] == anchors[-1]).all()  # three stride-32 layers share the 7x7 grid


def test_decoding_offsets_boxes_and_points_from_their_anchor() -> None:
    anchors = ssd_anchor_centres()
    raw = np.zeros((len(anchors), 12), np.float32)
    scores = np.full((len(anchors), 1), -20.0, np.float32)
    k = 1000
    raw[k, :4] = [11.2, -22.4, 44.8, 89.6]  # dx, dy, w, h in detector pixels
    raw[k, 4:6] = [5.6, 0.0]
    scores[k] = 3.0
    found = decode_detections(raw, scores, anchors, min_score=0.5)
    assert len(found) == 1
    cx, cy = anchors[k] + [0.05, -0.1]
    np.testing.assert_allclose(found.boxes[0], [cx - 0.1, cy - 0.2, cx + 0.1, cy + 0.2], atol=1e-6)
    np.testing.assert_allclose(found.points[0, 0], anchors[k] + [0.025, 0.0], atol=1e-6)
    assert found.scores[0] == pytest.approx(1 / (1 + np.exp(-3.0)))
    assert DETECTOR_SIZE == 224


def test_weighted_suppression_blends_overlapping_detections() -> None:
    boxes = np.array([[0, 0, 10, 10], [1, 0, 11, 10], [50, 50, 60, 60]], float)
    points = np.zeros((3, 4, 2))
    points[:, 0] = [[5, 5], [6, 5], [55, 55]]
    found = weighted_nms(Detections(boxes, points, np.array([0.9, 0.3, 0.5])), iou_threshold=0.3)
    assert len(found) == 2
    np.testing.assert_allclose(found.boxes[0], [0.25, 0, 10.25, 10])  # (0.9 * 0 + 0.3 * 1) / 1.2
    np.testing.assert_allclose(found.points[0, 0], [5.25, 5])
    assert found.scores.tolist() == [0.9, 0.5]


def test_heatmap_refinement_moves_a_landmark_to_the_peak_cell_centre() -> None:
    raw = np.zeros(LANDMARK_COUNT * LANDMARK_VALUES, np.float32)
    raw[0:2] = [100.0, 60.0]  # landmark 0, crop pixels
    heatmap = np.full((64, 64, LANDMARK_COUNT), -20.0, np.float32)
    heatmap[16, 26, 0] = 20.0  # one confident cell near (100, 60) / 4
    refined = refine_with_heatmap(raw, heatmap).reshape(-1, LANDMARK_VALUES)
    np.testing.assert_allclose(refined[0, :2], [(26 + 0.5) * 4, (16 + 0.5) * 4], atol=1e-3)
    heatmap[16, 26, 0] = -20.0  # not confident: unchanged
    np.testing.assert_allclose(refine_with_heatmap(raw, heatmap)[0:2], [100.0, 60.0])


def test_mirroring_twice_is_the_identity_and_swaps_sides() -> None:
    order = mirror_permutation()
    assert (order[order] == np.arange(LANDMARK_COUNT)).all()
    assert order[11] == 12 and order[0] == 0 and order[33] == 33
    rng = np.random.default_rng(0)
    raw = rng.uniform(0, LANDMARK_SIZE, LANDMARK_COUNT * LANDMARK_VALUES)
    world = rng.normal(size=LANDMARK_COUNT * 3)
    segmentation = rng.random((LANDMARK_SIZE, LANDMARK_SIZE))
    once = unmirror(raw, world, segmentation)
    twice = unmirror(*once)
    for a, b in zip(twice, (raw, world, segmentation)):
        np.testing.assert_allclose(a, b)
    np.testing.assert_allclose(once[0].reshape(-1, 5)[11, 0], LANDMARK_SIZE - raw.reshape(-1, 5)[12, 0])


# --- appearance, frame times ----------------------------------------------------------------------------------

def test_appearance_tells_colours_apart() -> None:
    image = np.zeros((40, 20, 3), np.uint8)
    image[:20] = [200, 30, 30]  # red top
    image[20:] = [30, 30, 200]  # blue bottom
    mask = np.ones((40, 20), bool)
    look = appearance(image, mask, 20, bins=12)
    assert appearance_distance(look, look) == pytest.approx(0.0, abs=1e-6)
    swapped = appearance(image[::-1].copy(), mask, 20, bins=12)
    assert appearance_distance(look, swapped) > 0.9
    empty = appearance(image, np.zeros_like(mask), 20, bins=12)
    assert appearance_distance(look, empty) == 1.0  # nothing to compare


def test_the_models_threads_follow_compute_threads_unless_set() -> None:
    from glimpse.compute import usable_cores
    from glimpse.errors import GlimpseError
    from glimpse.ingest.config import load_ingest_config

    assert load_ingest_config("compute.threads=3").threads == 3
    assert load_ingest_config("compute.threads=auto").threads == usable_cores()
    assert load_ingest_config("compute.threads=3 ingest.threads=1").threads == 1
    with pytest.raises(GlimpseError, match="ingest: threads must be auto or a number"):
        load_ingest_config("ingest.threads=-1")


def test_frame_grid_follows_timestamps() -> None:
    constant = [k / 10 for k in range(10)]
    assert grid_choice(constant, 10.0, 100) == {k: k for k in range(10)}
    assert grid_choice(constant, 5.0, 100) == {0: 0, 2: 1, 4: 2, 6: 3, 8: 4}
    assert grid_choice(constant, 10.0, 3) == {0: 0, 1: 1, 2: 2}
    variable = [0.0, 0.1, 0.2, 0.5, 0.6]  # a pause: the frame at 0.2 s stays on screen until 0.5 s
    assert grid_choice(variable, 10.0, 100) == {0: 0, 1: 1, 2: 2, 3: 5, 4: 6}
    # a part: the ids of the whole video's grid, the frame on screen at each grid time even if it began before
    assert grid_choice(constant, 10.0, 100, start_s=0.3, end_s=0.6) == {3: 3, 4: 4, 5: 5, 6: 6}
    assert grid_choice(constant, 5.0, 2, start_s=0.3) == {4: 2, 6: 3}
    assert grid_choice(variable, 10.0, 100, start_s=0.3) == {2: 3, 3: 5, 4: 6}
    assert grid_choice(constant, 10.0, 100, start_s=1.5) == {}


# --- evaluation -----------------------------------------------------------------------------------------------

def _person(x0: int, visible: bool = True) -> tuple[TruePerson, FoundPerson]:
    mask = np.zeros((20, 40), bool)
    mask[2:18, x0:x0 + 8] = True
    joints = np.stack([np.full(17, x0 + 4.0), np.linspace(3, 17, 17)], 1)
    keypoints = np.concatenate([joints + 0.3, np.ones((17, 1))], 1)  # 0.42 px off; torso 7 px
    return TruePerson(mask, joints, np.full(17, visible)), FoundPerson(mask, keypoints)


def test_scores_count_recall_switches_and_pck() -> None:
    truth, found = {}, {}
    for frame in range(6):
        a_true, a_found = _person(2)
        b_true, _ = _person(25)
        truth[frame] = {"a": a_true, "b": b_true}
        found[frame] = {"x": a_found} if frame != 2 else {}  # a missed once; b never found
        if frame >= 3:
            found[frame] = {"y": a_found}  # a's id changes at frame 3
    scores = score_people(truth, found, pck_fraction=0.1)
    assert scores["a"].recall == pytest.approx(5 / 6) and scores["a"].switches == 1
    assert scores["a"].ids == ("x", "y") and scores["a"].mask_iou == pytest.approx(5 / 6)
    # the missed frame's joints count as not found, as its mask counts IoU 0
    assert scores["a"].pck == pytest.approx(5 / 6) and scores["a"].pck_silhouette == pytest.approx(5 / 6)
    assert scores["b"].recall == 0.0 and scores["b"].mask_iou == 0.0 and scores["b"].pck == 0.0
    # found by a mask alone (no keypoints) in the frame it was missed: the same PCK, a higher recall
    found[2] = {"x": FoundPerson(found[0]["x"].mask, np.zeros((17, 3)))}
    again = score_people(truth, found, pck_fraction=0.1)["a"]
    assert again.recall == 1.0 and again.pck == pytest.approx(5 / 6)


def test_joints_behind_the_persons_own_body_are_not_counted_in_pck_but_reported() -> None:
    from glimpse.ingest.evaluate import in_front_of_own_body

    # chest surface 2.0 m away; a near elbow 3 cm under its skin at 2.02 m; a far elbow behind the chest at
    # 2.25 m, 3 cm under its own skin; a joint where no body surface is drawn
    in_front = in_front_of_own_body(np.array([2.02, 2.25, 2.4]), np.array([2.0, 2.0, 0.0]),
                                    np.array([0.03, 0.03, 0.03]), margin=0.05)
    assert in_front.tolist() == [True, False, True]
    a_true, a_found = _person(2)
    hidden = np.zeros(17, bool)
    hidden[[7, 9]] = True  # far elbow and wrist, reported far off by the finder
    keypoints = a_found.keypoints.copy()
    keypoints[[7, 9], :2] += 50
    truth = {0: {"a": TruePerson(a_true.mask, a_true.joints, a_true.visible, ~hidden)}}
    scores = score_people(truth, {0: {"x": FoundPerson(a_found.mask, keypoints)}}, pck_fraction=0.1)
    assert scores["a"].pck == 1.0 and scores["a"].pck_silhouette == pytest.approx(15 / 17)
    assert scores["a"].hidden_reported == 1.0


def test_joints_outside_the_image_that_the_ingest_reported_are_counted() -> None:
    a_true, a_found = _person(2)
    joints = a_true.joints.copy()
    joints[[9, 10], 0] = [-3.0, -8.0]  # both wrists left the 40 x 20 image on the left
    joints[15, 1] = 19.4  # an ankle on the last row: inside
    keypoints = a_found.keypoints.copy()
    keypoints[10, 2] = 0.0  # one wrist not reported, the other squeezed inside the border
    truth = {0: {"a": TruePerson(a_true.mask, joints, a_true.visible)}}
    scores = score_people(truth, {0: {"x": FoundPerson(a_found.mask, keypoints)}}, pck_fraction=0.1)
    assert scores["a"].outside_reported == 0.5
    scores = score_people({0: {"a": a_true}}, {0: {"x": a_found}}, pck_fraction=0.1)
    assert np.isnan(scores["a"].outside_reported)  # nothing outside: nothing to report


def test_mirrored_landmarks_are_paired_side_by_side_before_averaging() -> None:
    from glimpse.ingest.blazepose import sides_to_swap, swap_sides

    reference = np.zeros((LANDMARK_COUNT, LANDMARK_VALUES))
    reference[25, :2], reference[26, :2] = [100, 200], [140, 200]  # left and right knee
    other = reference.copy()
    other[[25, 26]] = other[[26, 25]]  # the mirrored run called them the other way round
    other[0, :2] = [5, 5]
    paired = swap_sides(other, sides_to_swap(reference, other))
    np.testing.assert_allclose(paired[[25, 26], :2], reference[[25, 26], :2])
    np.testing.assert_allclose(paired[0, :2], [5, 5])  # unpaired landmarks untouched


def test_a_mirrored_run_names_the_legs_otherwise_when_half_of_their_pairs_were_swapped() -> None:
    from glimpse.ingest.blazepose import legs_named_otherwise

    assert legs_named_otherwise([(25, 26), (27, 28)])  # knees and ankles: half of the four leg pairs
    assert legs_named_otherwise([(11, 12), (25, 26), (27, 28), (29, 30), (31, 32)])
    assert not legs_named_otherwise([(27, 28)])  # the ankles alone: a pair of close points, not the legs
    assert not legs_named_otherwise([(11, 12), (13, 14), (15, 16)])  # shoulders and arms: not the legs


def test_smoothing_keeps_straight_motion_removes_jitter_and_never_invents() -> None:
    from glimpse.ingest.smoothing import smooth_keypoints

    frames = np.arange(10)
    straight = np.zeros((10, 2, 3))
    straight[:, :, 0] = frames[:, None] * 3.0 + 7.0  # moving 3 px a frame
    straight[:, :, 1] = 50.0
    straight[:, :, 2] = 1.0
    np.testing.assert_allclose(smooth_keypoints(frames, straight, 2), straight, atol=1e-9)
    noisy = straight.copy()
    noisy[:, :, 1] += np.where(frames % 2, 2.0, -2.0)[:, None]  # +-2 px jitter
    smoothed = smooth_keypoints(frames, noisy, 2)
    assert np.abs(smoothed[2:-2, :, 1] - 50.0).max() < np.abs(noisy[2:-2, :, 1] - 50.0).max() / 2
    noisy[4, 0, 2] = 0.0
    noisy[4, 0, :2] = 0.0
    out = smooth_keypoints(frames, noisy, 2)
    assert out[4, 0].tolist() == [0.0, 0.0, 0.0]  # missing stays missing
    np.testing.assert_allclose(out[:, :, 2], noisy[:, :, 2])  # confidences untouched
    np.testing.assert_allclose(smooth_keypoints(frames, noisy, 0), noisy)
    in_3d = np.concatenate([noisy[:, :, :2], np.full((10, 2, 1), 0.3), noisy[:, :, 2:]], axis=2)  # x, y, z, conf
    out_3d = smooth_keypoints(frames, in_3d, 2)
    np.testing.assert_allclose(out_3d[..., [0, 1, 3]], out, atol=1e-9)  # same fit per coordinate
    np.testing.assert_allclose(out_3d[..., 2][noisy[..., 2] > 0], 0.3)


def test_metric_landmarks_are_turned_from_the_crop_onto_the_image_axes() -> None:
    from dataclasses import replace

    from glimpse.ingest.blazepose import BODY_LANDMARKS, COCO17_FROM_BLAZEPOSE

    world = np.zeros((BODY_LANDMARKS, 3))
    nose = COCO17_FROM_BLAZEPOSE[0]
    world[nose] = [0.0, -0.6, 0.1]  # 60 cm up the crop, 10 cm away from the camera
    upright = _landmarks_at(np.zeros((BODY_LANDMARKS, 2)), Region(np.zeros(2), 80.0, 0.0))
    np.testing.assert_allclose(replace(upright, world=world).coco17_relative3d()[0], [0.0, -0.6, 0.1])
    # a person lying along the image's x axis, head to the right: the crop is turned so the body is upright;
    # the crop's x axis points along the image's y, its y (towards the feet) along the image's -x
    lying = replace(upright, world=world, region=Region(np.zeros(2), 80.0, np.pi / 2))
    np.testing.assert_allclose(lying.coco17_relative3d()[0], [0.6, 0.0, 0.1], atol=1e-12)


# --- tracks behind other people -------------------------------------------------------------------------------

def _landmarks_at(points: np.ndarray, region: Region):
    from glimpse.ingest.blazepose import BODY_LANDMARKS, PoseLandmarks

    return PoseLandmarks(points=points, visibility=np.ones(BODY_LANDMARKS), presence=np.ones(BODY_LANDMARKS),
                         world=np.zeros((BODY_LANDMARKS, 3)), score=1.0, next_region=region,
                         segmentation=np.zeros((LANDMARK_SIZE, LANDMARK_SIZE)), region=region)


def test_a_hidden_track_is_expected_where_its_velocity_takes_it() -> None:
    from glimpse.ingest.blazepose import BODY_LANDMARKS
    from glimpse.ingest.observation import Track

    region = Region(np.array([100.0, 100.0]), 80.0, 0.0)
    landmarks = _landmarks_at(np.tile([100.0, 100.0], (BODY_LANDMARKS, 1)), region)
    track = Track(0, landmarks, np.zeros((2, 4)), velocity=np.array([5.0, -1.0]), missing=2)
    np.testing.assert_allclose(track.predicted_landmarks().points, np.tile([115.0, 97.0], (BODY_LANDMARKS, 1)))
    np.testing.assert_allclose(track.predicted_region().centre, [115.0, 97.0])


def test_a_second_wrong_fit_of_one_person_is_the_same_person_but_a_neighbour_is_not() -> None:
    from glimpse.ingest.blazepose import BODY_LANDMARKS, COCO17_FROM_BLAZEPOSE
    from glimpse.ingest.config import load_ingest_config
    from glimpse.ingest.observation import same_person

    config = load_ingest_config()
    region = Region(np.array([100.0, 150.0]), 200.0, 0.0)
    body = np.zeros((BODY_LANDMARKS, 2))
    coco = np.array(COCO17_FROM_BLAZEPOSE)
    body[coco] = np.stack([np.full(17, 100.0), np.linspace(60.0, 260.0, 17)], 1)  # a standing figure
    body[[11, 12]] = [[90.0, 110.0], [110.0, 110.0]]  # shoulders
    body[[23, 24]] = [[92.0, 190.0], [108.0, 190.0]]  # hips: torso length 80 px
    person = _landmarks_at(body, region)
    wrong_limbs = body.copy()
    wrong_limbs[coco[7:]] += [60.0, 0.0]  # same head and shoulders, arms, hips and legs 0.75 torso away
    assert same_person(person, _landmarks_at(wrong_limbs, region), config)
    neighbour = body + [30.0, 0.0]  # a person beside: every point 0.375 torso lengths away
    assert not same_person(person, _landmarks_at(neighbour, region), config)
    assert same_person(person, _landmarks_at(body + [8.0, 0.0], region), config)  # 0.1 torso: the same


def test_only_unseen_tracks_overlapping_someone_found_look_behind() -> None:
    from glimpse.ingest.blazepose import BODY_LANDMARKS
    from glimpse.ingest.observation import Observation, Track
    from glimpse.ingest.tracker import Tracker

    def track(index: int, x: float) -> Track:
        region = Region(np.array([x, 100.0]), 80.0, 0.0)
        return Track(index, _landmarks_at(np.zeros((BODY_LANDMARKS, 2)), region), np.zeros((2, 4)))

    found_region = Region(np.array([100.0, 100.0]), 80.0, 0.0)
    found = Observation(_landmarks_at(np.zeros((BODY_LANDMARKS, 2)), found_region), np.zeros((1, 1)),
                        np.zeros((1, 1), bool), np.zeros(4), np.zeros((2, 4)), 1.0, np.zeros((17, 3)))
    live = [track(0, 100.0), track(1, 150.0), track(2, 400.0)]  # 0 is the one found; 1 overlaps it; 2 is far
    tracker = Tracker.__new__(Tracker)
    assert tracker._hidden_by_others(live, {0: found}) == {1}
    assert tracker._hidden_by_others(live, {}) == set()


def test_tracks_too_short_too_small_or_upside_down_are_dropped_and_counted() -> None:
    from types import SimpleNamespace

    from glimpse.ingest.blazepose import BODY_LANDMARKS
    from glimpse.ingest.config import load_ingest_config
    from glimpse.ingest.report import tracks_report
    from glimpse.ingest.stage import _kept_people
    from glimpse.ingest.observation import Track

    config = load_ingest_config()
    survey = SimpleNamespace(width=640, height=480, track_width=640, track_height=480, fps=10.0, static=True)
    region = Region(np.array([100.0, 100.0]), 80.0, 0.0)

    def track(index: int, frames: int, height: float) -> Track:
        t = Track(index, _landmarks_at(np.zeros((BODY_LANDMARKS, 2)), region), np.zeros((2, 4)))
        t.frames = list(range(frames))
        t.keypoints = [np.ones((17, 3))] * frames
        t.relative3d = [np.ones((17, 4))] * frames
        t.boxes = [np.array([10.0, 10.0, 30.0, 10.0 + height])] * frames
        t.legs_disputed = [0.0] * frames
        return t

    tall = track(0, config.track_min_frames, 0.5 * 480)
    small = track(1, 40, 0.5 * config.track_min_height * 480)  # a pattern on the floor, followed for long
    short = track(2, config.track_min_frames - 1, 0.5 * 480)
    filled_up = track(3, config.track_min_frames + 1, 0.5 * 480)  # long enough only with two frames looked at again
    filled_up.looked_again = [0, 1]
    standing = np.zeros((17, 3))
    standing[:, 2] = 1.0
    standing[[5, 6], 1], standing[[11, 12], 1] = 100.0, 200.0  # shoulders above the hips (image y down)
    on_its_head = standing.copy()
    on_its_head[:, 1] = 300.0 - standing[:, 1]
    frames = 10
    upside_down = track(4, frames, 0.5 * 480)  # a pattern on a wall, on its head in every frame showing its torso
    upside_down.keypoints = [on_its_head] * (frames - 2) + [np.zeros((17, 3))] * 2
    handstand = track(5, frames, 0.5 * 480)  # on its hands in fewer frames than the limit allows
    inverted = int(config.track_max_upside_down * frames)
    handstand.keypoints = [on_its_head] * inverted + [standing] * (frames - inverted)
    people, dropped = _kept_people([tall, small, short, filled_up, upside_down, handstand], survey, config,
                                   lambda frame_id: np.zeros((480, 640), np.uint16))
    assert [p.label for p in people] == [1, 6] and dropped == {"short": 2, "small": 1, "upside_down": 1}
    report = tracks_report(people, dropped, {})
    assert report["dropped_short_tracks"] == 2 and report["dropped_small_tracks"] == 1
    assert report["dropped_upside_down_tracks"] == 1


def test_upside_down_share_counts_only_frames_showing_the_torso() -> None:
    from glimpse.ingest.upright import upside_down_share

    def frame(shoulder_xy: tuple[float, float], hip_xy: tuple[float, float], seen: float = 1.0) -> np.ndarray:
        keypoints = np.zeros((17, 3))
        keypoints[[5, 6], :2], keypoints[[11, 12], :2] = shoulder_xy, hip_xy
        keypoints[[5, 6, 11, 12], 2] = seen
        return keypoints

    upright, on_its_head = frame((50, 10), (50, 60)), frame((50, 60), (50, 10))
    lying = frame((100, 50), (50, 50))  # torso level: 90 degrees from up
    tilted_down = frame((60, 60), (50, 10))  # 169 degrees from up
    unseen = frame((50, 60), (50, 10), seen=0.0)
    assert upside_down_share(np.stack([upright, on_its_head, lying, tilted_down, unseen])) == 0.5
    assert upside_down_share(np.stack([unseen])) == 0.0


def test_a_track_does_not_follow_onto_someone_who_looks_different(monkeypatch) -> None:
    from dataclasses import replace

    from glimpse.ingest.blazepose import BODY_LANDMARKS
    from glimpse.ingest.config import load_ingest_config
    from glimpse.ingest.observation import Observation, Track
    from glimpse.ingest.tracker import Tracker

    config = replace(load_ingest_config(), keypoint_crop_shifts=[])  # no model here to take the keypoints again
    region = Region(np.array([100.0, 100.0]), 80.0, 0.0)
    red, blue = np.zeros((2, 36)), np.zeros((2, 36))
    red[:, 0], blue[:, 20] = 1.0, 1.0  # all their pixels in one, different, hue bin
    tracker = Tracker.__new__(Tracker)
    tracker.config, tracker.pose = config, None
    monkeypatch.setattr(Tracker, "_find_new", lambda self, image, observed: [])
    unseen = np.full((2, 36), np.nan)  # no pixels to tell by: followed, as before
    for found_look, followed in ((red, True), (blue, False), (unseen, True)):
        track = Track(0, _landmarks_at(np.full((BODY_LANDMARKS, 2), 100.0), region), red.copy())
        tracker.tracks = [track]
        seen = Observation(_landmarks_at(np.full((BODY_LANDMARKS, 2), 100.0), region), np.zeros((200, 200)),
                           np.zeros((200, 200), bool), np.array([90.0, 60.0, 110.0, 140.0]), found_look, 1.0,
                           np.ones((17, 3)))
        monkeypatch.setattr(Tracker, "observe", lambda self, image, where, seen=seen: seen)
        result = tracker.step(0, np.zeros((200, 200, 3), np.uint8))
        assert (len(result) == 1) == followed and track.missing == (0 if followed else 1)


def test_a_checkpoint_round_trips_and_a_foreign_or_broken_one_is_not_used(tmp_path) -> None:
    from glimpse.ingest.blazepose import BODY_LANDMARKS
    from glimpse.ingest.checkpoint import load_checkpoint, save_checkpoint
    from glimpse.ingest.observation import Track

    rng = np.random.default_rng(0)
    region = Region(np.array([100.0, 120.0]), 80.0, 0.3)
    track = Track(3, _landmarks_at(rng.normal(size=(BODY_LANDMARKS, 2)), region), rng.random((2, 36)),
                  velocity=np.array([1.5, -0.5]), missing=2, frames=[4, 5], keypoints=[rng.random((17, 3))] * 2,
                  relative3d=[rng.random((17, 4))] * 2, boxes=[rng.random(4)] * 2, reidentified=[(5, 0.25)],
                  jumps=[5], looked_again=[4])
    path = tmp_path / "checkpoint.npz"
    save_checkpoint(path, [track], 6, "key")
    (loaded,), done = load_checkpoint(path, "key")
    assert done == 6 and (loaded.index, loaded.missing, loaded.frames, loaded.jumps) == (3, 2, [4, 5], [5])
    assert loaded.reidentified == [(5, 0.25)] and loaded.looked_again == [4] and np.array_equal(loaded.look, track.look)
    assert np.array_equal(loaded.landmarks.points, track.landmarks.points)
    restored = loaded.landmarks.region
    assert np.array_equal(restored.centre, region.centre) and (restored.side, restored.angle) == (80.0, 0.3)
    assert np.array_equal(loaded.keypoints[1], track.keypoints[1])
    assert load_checkpoint(path, "another video") is None
    path.write_bytes(b"not a checkpoint")
    assert load_checkpoint(path, "key") is None


def test_foreground_blobs_of_people_side_by_side_are_also_looked_at_one_window_at_a_time() -> None:
    from dataclasses import replace

    from glimpse.ingest.config import load_ingest_config
    from glimpse.ingest.foreground import foreground_candidates

    config = replace(load_ingest_config(), foreground_person_aspect=0.35, foreground_region_grow=1.5)
    plate = np.full((240, 320, 3), 100, np.uint8)
    image = plate.copy()
    image[40:200, 60:110] = (200, 40, 40)  # two people, 160 px tall, touching: one blob 100 px wide
    image[40:200, 110:160] = (40, 200, 40)
    image[20:23, 290:293] = 255  # a speck: opened away
    image[60:200, 230:280] = (40, 40, 200)  # a third person, already found
    explained = np.zeros((240, 320), bool)
    explained[60:200, 230:280] = True
    candidates = foreground_candidates(image, plate, explained, config, person_side=0.0)
    # one blob, 100 / (0.35 * 160) -> 2 people: the whole blob, then each half with the other half painted
    assert len(candidates) == 3
    whole, left, right = candidates
    np.testing.assert_allclose(whole.region.centre, [109.5, 119.5])
    assert whole.region.side == pytest.approx(160 * 1.5)
    np.testing.assert_allclose([left.region.centre[0], right.region.centre[0]], [84.5, 134.5])
    assert left.paint[100, 130] and not left.paint[100, 80] and right.paint[100, 80] and not right.paint[100, 130]
    assert all(c.paint[100, 250] for c in candidates)  # the person found is painted over for every look
    assert not whole.paint[100, 80] and not whole.paint[100, 130]
    single = foreground_candidates(image[:, :110], plate[:, :110], explained[:, :110], config, person_side=300.0)
    assert len(single) == 1 and single[0].region.side == 300.0  # one person wide: one look, at least person_side


def test_a_new_person_or_one_found_behind_someone_lying_mostly_on_them_is_not_taken() -> None:
    from glimpse.ingest.blazepose import BODY_LANDMARKS
    from glimpse.ingest.config import load_ingest_config
    from glimpse.ingest.observation import Observation
    from glimpse.ingest.tracker import Tracker

    def observation(x: float, body: np.ndarray) -> Observation:
        region = Region(np.array([x, 50.0]), 80.0, 0.0)
        return Observation(_landmarks_at(np.tile([x, 50.0], (BODY_LANDMARKS, 1)), region), np.zeros((100, 100)),
                           body, np.array([x - 5, 10, x + 5, 90]), np.zeros((2, 4)), 1.0, np.ones((17, 3)), body=body)

    tracker = Tracker.__new__(Tracker)
    tracker.config = load_ingest_config()
    found_body = np.zeros((100, 100), bool)
    found_body[10:90, 40:60] = True
    found = observation(50.0, found_body)
    on_them = np.zeros((100, 100), bool)
    on_them[10:90, 45:62] = True  # 15 of its 17 columns on the found person's body
    beside = np.zeros((100, 100), bool)
    beside[10:90, 55:75] = True  # 5 of 20 columns
    for body, x, taken in ((on_them, 53.0, False), (beside, 65.0, True)):
        fresh: list[Observation] = []
        tracker._keep_new(observation(x, body), [found], fresh)
        assert (len(fresh) == 1) == taken
    partly = np.zeros((100, 100), bool)
    partly[10:90, 48:68] = True  # 12 of 20 columns on them: too much for a new person, not for a look behind
    assert tracker._taken(observation(58.0, partly), [found], tracker.config.track_new_max_overlap)
    assert not tracker._taken(observation(58.0, partly), [found], tracker.config.track_behind_max_overlap)


def test_contested_mask_pixels_go_to_the_person_whose_feet_are_lower_or_whose_bones_say_nearer() -> None:
    from glimpse.ingest.blazepose import BODY_LANDMARKS
    from glimpse.ingest.depth_order import depth_ordered_labels
    from glimpse.ingest.observation import Observation, Track

    shape = (120, 100)

    def person(index: int, feet_row: float, depth: float) -> tuple[Track, Observation]:
        points = np.column_stack([np.full(BODY_LANDMARKS, 50.0), np.linspace(20.0, feet_row, BODY_LANDMARKS)])
        landmarks = _landmarks_at(points, Region(np.array([50.0, 60.0]), 100.0, 0.0))
        claim = np.zeros(shape, np.float32)
        claim[20:100, 40:60] = 1.0  # both segmentations claim the same pixels, both skeletons run through them
        observation = Observation(landmarks, claim, claim > 0.5, np.array([45.0, 20.0, 55.0, feet_row]),
                                  np.zeros((2, 4)), depth, np.ones((17, 3)))
        return Track(index, landmarks, np.zeros((2, 4))), observation

    adult_behind = person(0, feet_row=90.0, depth=0.004)  # feet higher up the image; adult bones: ranked near
    child_in_front = person(1, feet_row=110.0, depth=0.006)  # an adult's bone lengths given to a child: "far"
    pair = [adult_behind, child_in_front]
    assert depth_ordered_labels(pair, shape, 0.5, 0.25, cue="feet")[60, 50] == 2  # the child keeps its pixels
    assert depth_ordered_labels(pair, shape, 0.5, 0.25, cue="bones")[60, 50] == 1


def test_feet_rank_people_by_their_recent_median_so_a_hidden_persons_guessed_feet_do_not_win() -> None:
    from glimpse.ingest.depth_order import nearness_rank
    from glimpse.ingest.observation import Observation, Track

    def track_with_feet(rows: list[float]) -> tuple[Track, Observation]:
        boxes = [np.array([0.0, 0.0, 10.0, row]) for row in rows]
        track = Track(0, None, np.zeros((2, 4)), frames=list(range(10, 10 + len(rows))), boxes=boxes)
        observation = Observation(None, None, None, boxes[-1], np.zeros((2, 4)), 0.0, np.ones((17, 3)))
        return track, observation

    # hidden behind a child, the adult's feet are guessed onto the child's (row 544) for two frames
    adult = track_with_feet([480.0, 490.0, 495.0, 500.0, 502.0, 544.0, 540.0])
    child = track_with_feet([530.0, 534.0, 536.0, 537.0, 538.0, 537.0, 538.0])
    assert nearness_rank(*adult, "feet", 1) < nearness_rank(*child, "feet", 1)  # this frame alone: adult nearer
    assert nearness_rank(*child, "feet", 7) < nearness_rank(*adult, "feet", 7)  # recent median: the child
    assert nearness_rank(*adult, "feet", 7) == -500.0
    old = track_with_feet([600.0, 600.0, 600.0, 480.0])
    old[0].frames[:3] = [0, 1, 2]  # seen long before the window: not counted
    assert nearness_rank(*old, "feet", 7) == -480.0


def test_people_the_plate_holds_are_painted_with_their_surroundings_not_with_the_plate() -> None:
    from dataclasses import replace

    from glimpse.ingest.config import load_ingest_config
    from glimpse.ingest.foreground import surroundings_fill
    from glimpse.ingest.tracker import Tracker

    image = np.zeros((240, 320, 3), np.uint8)
    image[:, :160] = (200, 40, 40)
    image[:, 160:] = (40, 40, 200)
    person = np.zeros((240, 320), bool)
    person[80:200, 10:40] = True  # inside the red half, 120 px (2.5 sigmas of the fill) from the blue one
    image[person] = (20, 200, 20)
    fill = surroundings_fill(image, person)
    np.testing.assert_allclose(fill[140, 25], (200, 40, 40), atol=6)  # the person's own pixels do not count
    tracker = Tracker.__new__(Tracker)
    tracker.config = replace(load_ingest_config(), paint_still_with="surroundings")
    moved = np.zeros_like(person)
    moved[80:200, 200:240] = True  # a second person, who walked: the plate shows the background behind them
    image[moved] = (20, 200, 20)
    tracker.plate = image.copy()
    tracker.plate[moved] = (40, 40, 200)  # the first stood still all video: the plate shows them
    painted = tracker._painted_over(image, person | moved)
    np.testing.assert_allclose(painted[140, 25], (200, 40, 40), atol=6)
    assert np.array_equal(painted[140, 220], (40, 40, 200))
    assert np.array_equal(painted[~(person | moved)], image[~(person | moved)])


def test_people_the_plate_holds_can_be_painted_with_the_plates_texture_from_beside_them() -> None:
    from dataclasses import replace

    from glimpse.ingest.config import load_ingest_config
    from glimpse.ingest.foreground import beside_fill
    from glimpse.ingest.tracker import Tracker

    stripes = np.zeros((240, 320, 3), np.uint8)
    stripes[:, :, 0] = (np.arange(320) * 7 % 256)[None]  # a texture that says where each pixel came from
    stripes[:, :, 1] = np.arange(240)[:, None]
    pixels = np.zeros((240, 320), bool)
    pixels[80:200, 20:60] = True  # 40 px wide, near the left edge: the right side has all of its pixels
    pixels[10:30, 280:310] = True  # a second region, 30 px wide, near the right edge: the left side has them
    fill, given = beside_fill(stripes, pixels, 5)
    assert np.array_equal(given, pixels)
    assert np.array_equal(fill[80:200, 20:60], stripes[80:200, 65:105])  # shifted right by 40 + 5
    assert np.array_equal(fill[10:30, 280:310], stripes[10:30, 245:275])  # shifted left by 30 + 5
    blocked = pixels.copy()
    blocked[80:200, 60:80] = True  # the region grown to 60 px: its source moves past it, 65 px to the right
    fill, given = beside_fill(stripes, blocked, 5)
    assert given[100, 20:80].all() and not given[100, :20].any()
    assert np.array_equal(fill[100, 20:80], stripes[100, 85:145])
    blocked[80:200, 85:145] = True  # a region there too: the left side, where it is inside the frame (x >= 0)
    fill, given = beside_fill(stripes, blocked, 5)
    assert np.array_equal(given[100, 20:80], np.arange(20, 80) >= 65)
    assert np.array_equal(fill[100, 65:80], stripes[100, 0:15])

    tracker = Tracker.__new__(Tracker)
    tracker.config = replace(load_ingest_config(), paint_still_with="beside")
    image = stripes.copy()
    image[pixels] = (20, 200, 20)  # people who stood still all video: the plate shows them
    tracker.plate = image.copy()
    painted = tracker._painted_over(image, pixels)
    margin = round(0.02 * 240)  # the tracker's margin: STILL_WIDTH of the frame's height
    # inside the region (its corners, narrower than STILL_WIDTH, are left to the plate)
    assert np.array_equal(painted[90:190, 25:55], stripes[90:190, 65 + margin:95 + margin])
    assert np.array_equal(painted[~pixels], image[~pixels])
    walker = np.zeros_like(pixels)
    walker[60:220, 60:130] = True  # someone moving there now (the frame differs from the plate): not copied
    image[walker] = (250, 250, 250)
    painted = tracker._painted_over(image, pixels)
    assert not (painted[pixels] == (250, 250, 250)).all(axis=-1).any()
    shift = 40 + margin  # the region's width and the margin
    assert np.array_equal(painted[100, shift:60], stripes[100, 0:60 - shift])  # from the left, where it can (x >= 0)
    someone = np.zeros_like(pixels)
    someone[:, :20] = True  # a still person there, found (their body): not copied either
    painted = tracker._painted_over(image, pixels, someone)
    assert not (painted[100, shift:60] == stripes[100, 0:60 - shift]).all(axis=-1).any()


def test_a_new_person_who_looks_like_a_track_better_than_what_it_followed_is_that_tracks_person() -> None:
    from glimpse.ingest.blazepose import BODY_LANDMARKS
    from glimpse.ingest.claims import reclaim
    from glimpse.ingest.config import load_ingest_config
    from glimpse.ingest.observation import Observation, Track

    def look(red: float) -> np.ndarray:  # two halves of 4 bins, normalised
        half = np.array([red, 1.0 - red, 0.0, 0.0])
        return np.stack([half, half])

    def observation(x: float, colour: float) -> Observation:
        region = Region(np.array([x, 50.0]), 80.0, 0.0)
        return Observation(_landmarks_at(np.tile([x, 50.0], (BODY_LANDMARKS, 1)), region), None, None,
                           np.array([x - 10, 10, x + 10, 90]), look(colour), 1.0, np.ones((17, 3)))

    margin = load_ingest_config().track_reclaim_margin
    adult = Track(0, None, look(1.0))
    slid = observation(50.0, 0.6)  # half on the child in front: looks 0.6 like the adult
    followed = {0: slid}
    elsewhere, adult_found = observation(200.0, 1.0), observation(60.0, 0.95)
    fresh = [elsewhere, adult_found]
    reclaim(fresh, followed, [adult], margin)
    # far away: not the track's person, whatever they look like
    assert followed[0] is adult_found and len(fresh) == 1 and fresh[0] is elsewhere
    followed, fresh = {0: slid}, [observation(60.0, 0.65)]  # hardly better: a new person beside them
    reclaim(fresh, followed, [adult], margin)
    assert followed[0] is slid and len(fresh) == 1


def test_the_written_keypoints_are_the_median_over_crops_moved_sideways() -> None:
    """BlazePose.median_points: the region's own runs and those of its crop moved along the crop's x axis by
    +-shift x side, each with its mirror; one crop's gross error (a knee put on the other leg) does not move the
    median, where it would move a mean."""
    from dataclasses import replace

    from glimpse.ingest.blazepose import BODY_LANDMARKS, BlazePose

    truth = np.random.default_rng(0).uniform(100, 300, (BODY_LANDMARKS, 2))
    region = Region(np.array([200.0, 180.0]), 240.0, np.pi / 2)  # turned: the crop's x axis is the image's y
    image = np.zeros((400, 400, 3), np.uint8)

    class Crops(BlazePose):
        """Every crop's runs put the landmarks at ``truth``, but the first moved crop's mirrored run puts the left
        knee 60 crop pixels off."""

        def __init__(self) -> None:  # no model files
            self.regions: list[Region] = []

        def _crop_runs(self, image, region, refine, mirror):
            self.regions.append(region)
            to_crop = np.linalg.inv(np.vstack([crop_affine(region, LANDMARK_SIZE), [0, 0, 1]]))
            raw = np.zeros((LANDMARK_COUNT, LANDMARK_VALUES))
            raw[:BODY_LANDMARKS, :2] = (np.c_[truth, np.ones(BODY_LANDMARKS)] @ to_crop.T)[:, :2] + 0.5
            wrong = raw.copy()
            wrong[25, :2] += 60.0 if len(self.regions) == 1 else 0.0
            runs = [(raw.ravel(), 1.0, None, None), (wrong.ravel(), 1.0, None, None)]
            return (runs, [len(self.regions) == 2]) if mirror else (runs[1:], [])

    model = Crops()
    own_runs = replace(_landmarks_at(truth, region), run_points=np.stack([truth, truth]), legs_disputed=1.0)
    points, legs_disputed = model.median_points(image, own_runs, (0.05,), True, True)
    np.testing.assert_allclose(points, truth, atol=1e-9)
    assert legs_disputed == 2 / 3  # the region's own mirrored run and the second moved crop's, of three
    sideways = 0.05 * 240.0 * np.array([0.0, 1.0])
    np.testing.assert_allclose([r.centre for r in model.regions], [region.centre + sideways, region.centre - sideways],
                               atol=1e-9)
    assert all(r.side == region.side and r.angle == region.angle for r in model.regions)
    model.regions.clear()  # no mirrors: 3 runs, 1 of them off, still give the truth (their mean would not)
    one_run = replace(own_runs, run_points=truth[None])
    points, legs_disputed = model.median_points(image, replace(one_run, legs_disputed=0.0), (0.05,), True, False)
    np.testing.assert_allclose(points, truth, atol=1e-9)
    assert legs_disputed == 0.0  # no mirrored run: nothing disputed


def test_the_median_names_each_pair_as_most_crops_do_instead_of_putting_the_two_together() -> None:
    """A person facing the camera with their arms at rest may be taken, in some crops, for someone seen from behind
    (every left/right pair named the other way). BlazePose.median_points names each pair as most runs do, and the
    two points of a pair stay apart: a median across the two namings would put them together."""
    from dataclasses import replace

    from glimpse.ingest.blazepose import BODY_LANDMARKS, BlazePose

    region = Region(np.array([200.0, 200.0]), 240.0, 0.0)
    truth = np.random.default_rng(1).uniform(100, 300, (BODY_LANDMARKS, 2))
    truth[7], truth[8] = [180.0, 100.0], [220.0, 100.0]  # the ears, 40 px apart
    exchanged = truth.copy()
    exchanged[[7, 8]] = exchanged[[8, 7]]

    class Crops(BlazePose):
        """Each moved crop's two runs (the crop and its mirror) name the ears as the next pair of ``names`` do."""

        def __init__(self, *names: tuple[np.ndarray, np.ndarray]) -> None:  # no model files
            self.names = iter(names)

        def _crop_runs(self, image, region, refine, mirror):
            to_crop = np.linalg.inv(np.vstack([crop_affine(region, LANDMARK_SIZE), [0, 0, 1]]))
            runs = []
            for names in next(self.names):
                raw = np.zeros((LANDMARK_COUNT, LANDMARK_VALUES))
                raw[:BODY_LANDMARKS, :2] = (np.c_[names, np.ones(BODY_LANDMARKS)] @ to_crop.T)[:, :2] + 0.5
                runs.append((raw.ravel(), 1.0, None, None))
            return runs, [False]

    image = np.zeros((400, 400, 3), np.uint8)
    own_runs = replace(_landmarks_at(truth, region), run_points=np.stack([truth, truth]))
    # both moved crops (four runs of six) name the ears the other way: the median names them so, 40 px apart
    both = (exchanged, exchanged)
    points, _ = Crops(both, both).median_points(image, own_runs, (0.03,), True, True)
    np.testing.assert_allclose(points, exchanged, atol=1e-9)
    # an even split (three runs of six): the region's own name, the ears as far apart, not midway
    points, _ = Crops(both, (exchanged, truth)).median_points(image, own_runs, (0.03,), True, True)
    np.testing.assert_allclose(points, truth, atol=1e-9)


def test_landmarks_named_as_other_points_carry_each_joints_own_confidence_and_3d_point() -> None:
    from dataclasses import replace

    from glimpse.ingest.blazepose import BODY_LANDMARKS

    region = Region(np.array([200.0, 200.0]), 240.0, 0.0)
    points = np.random.default_rng(2).uniform(100, 300, (BODY_LANDMARKS, 2))
    visibility = np.linspace(0.1, 0.9, BODY_LANDMARKS)
    world = np.random.default_rng(3).normal(size=(BODY_LANDMARKS, 3))
    landmarks = replace(_landmarks_at(points, region), visibility=visibility, world=world)
    written = points + 1.0
    written[[11, 12]] = written[[12, 11]]  # the shoulders named the other way
    renamed = landmarks.named_as(written, 0.5)
    order = np.arange(BODY_LANDMARKS)
    order[[11, 12]] = [12, 11]
    np.testing.assert_array_equal(renamed.points, points[order])
    np.testing.assert_array_equal(renamed.visibility, visibility[order])
    np.testing.assert_array_equal(renamed.world, world[order])
    assert landmarks.named_as(points + 1.0, 0.5) is landmarks  # the same names: nothing to do
    near = points.copy()
    near[12] = near[11] + 1.0  # the shoulders a pixel apart (a side-on person): a median's noise decides their names
    noisy = near.copy()
    noisy[[11, 12]] = near[11] + [[0.6, 0.6], [0.4, -0.6]]  # nearer named the other way (0.85 times), not clearly
    assert replace(landmarks, points=near).named_as(noisy, 0.5).points is near
    assert replace(landmarks, points=near).named_as(noisy, 1.0).points is not near


def test_the_fit_settings_an_ingest_writes_and_the_zeros_that_write_none() -> None:
    from dataclasses import replace

    from glimpse.errors import GlimpseError
    from glimpse.ingest.config import load_ingest_config
    from glimpse.ingest.stage import fit_overrides

    config = replace(load_ingest_config(), fit_size_sigma=0.02, fit_keypoint_noise_m=0.04)
    assert fit_overrides(config)["02_smpl_fit"]["weights"] == {"size_sigma": 0.02, "keypoint_noise_m": 0.04}
    assert "weights" not in fit_overrides(replace(config, fit_size_sigma=0.0, fit_keypoint_noise_m=0.0))["02_smpl_fit"]
    assert fit_overrides(replace(config, fit_size_sigma=0.0))["02_smpl_fit"]["weights"] == {"keypoint_noise_m": 0.04}
    with pytest.raises(GlimpseError, match=r"ingest.fit_keypoint_noise_m must be 0 \(write none\) or more \(metres\), "
                                           r"found -0.01"):
        fit_overrides(replace(config, fit_keypoint_noise_m=-0.01))


def test_a_skeleton_squeezed_into_a_person_cut_by_the_border_is_found() -> None:
    from glimpse.ingest.sides import torso_lengths
    from glimpse.ingest.truncation import squeezed_at_border

    frames = 12
    times = np.arange(frames) / 10.0  # 10 fps
    keypoints = np.zeros((frames, 17, 3))
    keypoints[..., 2] = 0.9
    centre_x = np.linspace(600.0, 300.0, frames)  # walking left, entering from the right edge of a 640x480 frame
    torso = np.full(frames, 60.0)
    torso[0] = 42.0  # squeezed at the border (30% short)
    torso[8] = 45.0  # as short, far from any border: a bend, not a cut
    keypoints[:, [5, 6], 0], keypoints[:, [11, 12], 0] = centre_x[:, None], centre_x[:, None]
    keypoints[:, [5, 6], 1] = 200.0
    keypoints[:, [11, 12], 1] = 200.0 + torso[:, None]
    np.testing.assert_allclose(torso_lengths(keypoints), torso)
    boxes = np.stack([centre_x - 30, np.full(frames, 150.0), centre_x + 30, np.full(frames, 400.0)], 1)
    boxes[:2, 2] = 639.0  # the first two frames touch the right edge
    found = squeezed_at_border(times, keypoints, boxes, (640, 480), 0.05, 0.5, 0.15)
    assert found.tolist() == [True] + [False] * (frames - 1)  # frame 1 touches the edge at full size: kept
    # a frame whose torso is not found is not judged, and neither is one with no neighbour in the window
    keypoints[0, 11, 2] = 0.0
    assert not squeezed_at_border(times, keypoints, boxes, (640, 480), 0.05, 0.5, 0.15).any()
    keypoints[0, 11, 2] = 0.9
    assert not squeezed_at_border(times * 100, keypoints, boxes, (640, 480), 0.05, 0.5, 0.15).any()


def test_joints_on_another_persons_pixels_are_written_as_not_seen() -> None:
    from types import SimpleNamespace

    from glimpse.ingest.blazepose import BODY_LANDMARKS
    from glimpse.ingest.config import load_ingest_config
    from glimpse.ingest.occlusion import joints_on_others
    from glimpse.ingest.stage import _kept_people
    from glimpse.ingest.observation import Track

    labels = np.zeros((60, 80), np.uint16)
    labels[10:30, 20:40] = 2  # a nearer person (track index 1) in front
    labels[30:50, 20:40] = 1  # the person's own pixels
    points = np.array([[25.0, 15.0], [25.0, 35.0], [5.0, 5.0], [39.4, 29.6], [-3.0, 15.0], [90.0, 15.0]])
    assert joints_on_others(points, labels, 1).tolist() == [True, False, False, False, False, False]
    assert joints_on_others(points, labels, 2).tolist() == [False, True, False, True, False, False]

    config = load_ingest_config()
    survey = SimpleNamespace(width=80, height=60, track_width=80, track_height=60, fps=10.0, static=True)
    t = Track(0, _landmarks_at(np.zeros((BODY_LANDMARKS, 2)), Region(np.array([30.0, 30.0]), 40.0, 0.0)),
              np.zeros((2, 4)))
    t.frames = list(range(config.track_min_frames))
    keypoints = np.ones((17, 3))
    keypoints[:, :2] = [30.0, 40.0]  # on its own pixels
    keypoints[3, :2] = [30.0, 20.0]  # behind the other person
    t.keypoints = [keypoints.copy() for _ in t.frames]
    t.relative3d = [np.ones((17, 4)) for _ in t.frames]
    t.boxes = [np.array([20.0, 10.0, 40.0, 50.0]) for _ in t.frames]
    t.legs_disputed = [0.0 for _ in t.frames]
    people, _ = _kept_people([t], survey, config, lambda frame_id: labels)
    confidence = people[0].keypoints[..., 2]
    assert (confidence[:, 3] == 0).all() and (confidence[:, [0, 1, 2, 4]] > 0).all()
    assert (people[0].relative3d[:, 3, 3] == 0).all()


def test_only_someone_nearer_hides_a_joint() -> None:
    from glimpse.ingest.occlusion import hidden_joints, joints_on_others, lowest_rows

    labels = np.zeros((60, 80), np.uint16)
    labels[5:30, 10:30] = 2  # a person farther away (feet at row 29)
    labels[20:55, 25:45] = 1  # a person nearer (feet at row 54), in front of the other where they overlap
    labels[40:50, 60:70] = 3  # someone no track holds (a mask from the plate, say)
    assert lowest_rows(labels) == {1: 54.0, 2: 29.0, 3: 49.0}
    near = np.array([[15.0, 10.0], [35.0, 40.0], [65.0, 45.0]])  # on the farther one, its own pixels, on label 3
    far = np.array([[35.0, 25.0], [15.0, 10.0], [0.0, 0.0]])  # on the nearer one, its own pixels, nobody's
    assert joints_on_others(near, labels, 1, farther=[2]).tolist() == [False, False, True]
    assert joints_on_others(near, labels, 1).tolist() == [True, False, True]

    reads = []

    def labels_of(frame_id: int) -> np.ndarray:
        reads.append(frame_id)
        return labels

    frames = [0, 1, 2]
    hidden = hidden_joints([(1, frames, np.stack([near] * 3)), (2, frames[:2], np.stack([far] * 2))], labels_of, 1)
    assert hidden[0].tolist() == [[False, False, True]] * 3  # the farther one's pixels under its joint: kept
    assert hidden[1].tolist() == [[True, False, False]] * 2  # behind the nearer one
    assert sorted(reads) == [0, 0, 1, 1, 2, 2]  # each frame's labels read twice, whatever the number of people


def test_keypoints_outside_the_image_or_below_the_confidence_are_recorded_as_missing() -> None:
    from glimpse.ingest.tracker import recorded_keypoints

    keypoints = np.array([[10.0, 20.0, 0.9], [-3.0, 20.0, 0.9], [10.0, 20.0, 0.1], [99.6, 49.0, 0.5],
                          [99.4, 49.4, 0.3]])
    recorded = recorded_keypoints(keypoints, (50, 100), 0.2)
    np.testing.assert_array_equal(recorded[[0, 4]], keypoints[[0, 4]])  # inside (pixel centres up to 99.5, 49.5)
    np.testing.assert_array_equal(recorded[[1, 2, 3]], np.zeros((3, 3)))
