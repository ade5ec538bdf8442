"""Masks for the frames inside a track's gap, from what differs from a fixed camera's plate (glimpse.ingest.gap_masks):
which frames, which box, which pixels, when none, and how the frames join the person's track. The whole ingest runs
on rendered videos in test_ingest.py."""

from __future__ import annotations

import numpy as np
import pytest

from glimpse.ingest.config import load_ingest_config
from glimpse.ingest.gap_masks import (GapFrame, Sighting, colour_bins, colour_histogram, colour_log_ratio, gap_frames,
                                      gap_mask, interpolated_box, kept_only, mask_box, mean_colours, people_free_plate,
                                      sightings_in, taken_back, with_mask_frames)
from glimpse.ingest.report import PersonTrack

SIZE = (120, 200)  # H, W
GREY, FRONT, BEHIND = 100, 200, 30  # 8-bit levels of the plate and of two people's clothes


def test_gap_frames_are_the_missing_frames_of_short_gaps() -> None:
    frames = gap_frames([0, 1, 2, 5, 6, 20], max_frames=3)
    assert [(g.frame_id, g.before, g.after) for g in frames] == [(3, 2, 5), (4, 2, 5)]  # 7-19: 13 frames, too long
    assert [g.fraction for g in frames] == pytest.approx([1 / 3, 2 / 3])
    assert gap_frames([4, 5, 6], max_frames=30) == []


def test_interpolated_box_moves_over_time_and_grows_about_its_centre() -> None:
    before, after = np.array([0.0, 0.0, 10.0, 20.0]), np.array([20.0, 0.0, 30.0, 20.0])
    np.testing.assert_allclose(interpolated_box(before, after, 0.5, 1.0), [10.0, 0.0, 20.0, 20.0])
    np.testing.assert_allclose(interpolated_box(before, after, 0.25, 2.0), [0.0, -10.0, 20.0, 30.0])


def _scene() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A plate, a frame with one person in front (labelled) half hiding another (not found), the labels, and the
    hidden person's visible pixels."""
    plate = np.full((*SIZE, 3), GREY, np.uint8)
    image = plate.copy()
    behind = np.zeros(SIZE, bool)
    behind[20:100, 60:100] = True
    front = np.zeros(SIZE, bool)
    front[10:110, 85:125] = True
    image[behind] = BEHIND
    image[front] = FRONT
    labels = np.zeros(SIZE, np.uint16)
    labels[front] = 1
    return plate, image, labels, behind & ~front


def test_the_mask_is_what_differs_from_the_plate_and_nobody_holds() -> None:
    plate, image, labels, visible = _scene()
    config = load_ingest_config()
    box = np.array([55.0, 15.0, 105.0, 105.0])
    mine = gap_mask(image, plate, labels, box, expected_area=float(visible.sum()), config=config)
    assert mine is not None and not (mine & (labels > 0)).any()
    iou = (mine & visible).sum() / (mine | visible).sum()
    assert iou > 0.95
    # the box bounds it: the part of the hidden person outside the box is not taken
    narrow = gap_mask(image, plate, labels, np.array([70.0, 15.0, 105.0, 105.0]), float(visible.sum()), config)
    assert narrow is not None and not narrow[:, :69].any()


def test_a_dropped_tracks_pixels_are_nobodys() -> None:
    plate, image, labels, visible = _scene()
    labels[visible] = 7  # a short track, dropped after tracking, that had found the hidden person
    box, area = np.array([55.0, 15.0, 105.0, 105.0]), float(visible.sum())
    config = load_ingest_config()
    assert gap_mask(image, plate, labels, box, area, config) is None
    kept = kept_only(labels, [1])
    assert np.array_equal(kept > 0, labels == 1) and kept.dtype == labels.dtype
    mine = gap_mask(image, plate, kept, box, area, config)
    assert mine is not None and (mine & visible).sum() / (mine | visible).sum() > 0.95


def test_colour_log_ratio_is_the_histograms_log_ratio_at_each_pixel() -> None:
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (30, 40, 3), dtype=np.uint8)
    bins = 4
    mine = colour_histogram(image, image[..., 0] > 128, bins)
    theirs = colour_histogram(image, image[..., 0] <= 128, bins)
    assert mine.shape == (bins ** 3,) and mine.sum() == pytest.approx(1.0) and (mine > 0).all()
    # independently: each pixel's bin from its channels, then the ratio of the two histograms there
    r, g, b = (image[..., c].astype(int) // (256 // bins) for c in range(3))
    expected = np.log(mine[r * bins * bins + g * bins + b]) - np.log(theirs[r * bins * bins + g * bins + b])
    np.testing.assert_allclose(colour_log_ratio(colour_bins(image, bins), mine, theirs, 0.0), expected, rtol=1e-6)
    assert (expected[image[..., 0] > 128] > 0).mean() > 0.9  # the red half's own colours are likelier under its own


def _spread_scene() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[int, np.ndarray], np.ndarray]:
    """As _scene, but the segmentation of the person in front spreads over the hidden person's visible pixels, as
    BlazePose's does when it has lost the hidden one; with both people's colours as their masks around the gap
    show them (clothes of two shades each)."""
    plate, image, labels, visible = _scene()
    image[::2][image[::2] == BEHIND] = BEHIND + 20
    image[::2][image[::2] == FRONT] = FRONT - 20
    labels[visible] = 1
    hidden = colour_histogram(image, visible, 16)
    front = colour_histogram(image, (labels == 1) & ~visible, 16)
    return plate, image, labels, visible, {1: front}, hidden


def test_pixels_the_person_in_front_holds_are_taken_back_where_their_colours_say_so() -> None:
    plate, image, labels, visible, theirs, mine = _spread_scene()
    config = load_ingest_config()
    box = np.array([55.0, 15.0, 105.0, 105.0])
    taken = taken_back(image, labels, box, mine, theirs, config.gap_mask_take_ratio, sigma_px=1.0)
    assert (taken == visible).mean() > 0.99
    assert gap_mask(image, plate, labels, box, float(visible.sum()), config) is None  # without: nobody's pixels
    mask = gap_mask(image, plate, labels, box, float(visible.sum()), config, taken)
    assert mask is not None and (mask & visible).sum() / (mask | visible).sum() > 0.95
    # a holder whose colours are not known keeps its pixels; so does one dressed like the hidden person
    assert not taken_back(image, labels, box, mine, {1: None}, 2.0, 1.0).any()
    assert not taken_back(image, labels, box, mine, {1: mine}, 2.0, 1.0).any()
    # the box bounds it
    assert not taken_back(image, labels, np.array([80.0, 15.0, 105.0, 105.0]), mine, theirs, 2.0, 1.0)[:, :79].any()


def test_sightings_and_mean_colours_around_a_gap() -> None:
    _, image, labels, visible = _scene()
    labels[visible] = 2
    seen = sightings_in(image, labels, 5, bins=16)
    assert set(seen) == {(1, 5), (2, 5)}
    assert seen[2, 5].area == visible.sum()
    np.testing.assert_array_equal(seen[2, 5].box, mask_box(visible))
    np.testing.assert_allclose(seen[2, 5].colours, colour_histogram(image, visible, 16))
    other = {(2, 9): Sighting(seen[2, 5].box, 1, colour_histogram(image, labels == 1, 16))}
    gap = GapFrame(7, before=5, after=9, fraction=0.5)
    np.testing.assert_allclose(mean_colours(gap, 2, {**seen, **other}),
                               (seen[2, 5].colours + other[2, 9].colours) / 2)
    np.testing.assert_allclose(mean_colours(gap, 1, seen), seen[1, 5].colours)
    assert mean_colours(gap, 3, seen) is None


def test_no_mask_where_too_little_or_too_much_differs() -> None:
    plate, image, labels, visible = _scene()
    config = load_ingest_config()
    box = np.array([55.0, 15.0, 105.0, 105.0])
    area = float(visible.sum())
    assert gap_mask(image, plate, labels, box, area / (config.gap_mask_min_share * 0.9), config) is None  # hidden
    assert gap_mask(image, plate, labels, box, area / (config.gap_mask_max_share * 1.1), config) is None  # crowded
    assert gap_mask(plate.copy(), plate, labels, box, area, config) is None  # nothing differs


def test_the_plate_without_the_people_shows_where_someone_mostly_stood() -> None:
    """A person stands in one place in 6 of 10 sampled frames (a plain median shows them there) and someone else
    never leaves another place: the plate from the pixels nobody covers shows the background at the first and
    falls back to the given plate at the second."""
    background = np.random.default_rng(0).integers(0, 256, (*SIZE, 3), dtype=np.uint8)
    samples = np.repeat(background[None], 10, axis=0)
    people = np.zeros((10, *SIZE), bool)
    people[:6, 20:80, 30:60] = True
    samples[:6, 20:80, 30:60] = FRONT
    people[:, 20:80, 150:170] = True
    samples[:, 20:80, 150:170] = BEHIND
    median = np.median(samples, axis=0).astype(np.uint8)
    assert (median[20:80, 30:60] == FRONT).all()  # the plain median: the person
    fallback = np.full((*SIZE, 3), GREY, np.uint8)
    plate = people_free_plate(samples, people, fallback, margin_px=2, rows_at_once=16)
    np.testing.assert_array_equal(plate[20:80, 30:60], background[20:80, 30:60])
    assert (plate[20:80, 150:170] == GREY).all()  # nobody ever left: the given plate
    outside = np.ones(SIZE, bool)
    outside[18:82, 28:62] = outside[18:82, 148:172] = False
    np.testing.assert_array_equal(plate[outside], background[outside])


def test_mask_box() -> None:
    mask = np.zeros(SIZE, bool)
    mask[5:9, 20:31] = True
    np.testing.assert_array_equal(mask_box(mask), [20, 5, 30, 8])


def test_frames_with_a_mask_join_the_track_in_order_without_keypoints() -> None:
    keypoints = np.ones((3, 17, 3))
    person = PersonTrack("p0", 1, [2, 3, 7], keypoints, np.ones((3, 17, 4)), np.arange(12.0).reshape(3, 4), [], [])
    boxes = {4: np.full(4, 40.0), 6: np.full(4, 60.0)}
    joined = with_mask_frames(person, boxes)
    assert joined.frames == [2, 3, 4, 6, 7] and joined.masks_from_foreground == [4, 6]
    np.testing.assert_array_equal(joined.keypoints[[0, 1, 4]], keypoints)
    assert not joined.keypoints[[2, 3]].any() and not joined.relative3d[[2, 3]].any()
    np.testing.assert_array_equal(joined.boxes[[2, 3]], [boxes[4], boxes[6]])
    np.testing.assert_array_equal(joined.boxes[[0, 1, 4]], person.boxes)
    assert with_mask_frames(person, {}) is person
