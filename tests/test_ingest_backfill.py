"""Looking again at the frames a track missed (glimpse.ingest.backfill): where, in which order, what is kept, and
what the missed frames' labels become. The landmark model is replaced by a stand-in that finds a person wherever
it is told to, so that the rules are what is tested; the whole ingest runs on rendered videos in test_ingest.py."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from glimpse.ingest.backfill import fill_gaps, look_before_start, open_gaps
from glimpse.ingest.blazepose import BODY_LANDMARKS, LANDMARK_SIZE, REGION_GROW, PoseLandmarks
from glimpse.ingest.config import load_ingest_config
from glimpse.ingest.crop import Region
from glimpse.ingest.observation import Observation, Track
from glimpse.ingest.tracker import Tracker

SIZE = (120, 200)  # H, W of the frames
BOX_HEIGHT = 60.0


def _box_at(x: float) -> np.ndarray:
    return np.array([x - 10.0, 30.0, x + 10.0, 30.0 + BOX_HEIGHT])


def _observation(x: float, look: np.ndarray) -> Observation:
    """A person whose box is centred at column x; their mask and body: the box's pixels."""
    box = _box_at(x)
    region = Region(np.array([x, 60.0]), BOX_HEIGHT * REGION_GROW, 0.0)
    landmarks = PoseLandmarks(points=np.tile([x, 60.0], (BODY_LANDMARKS, 1)), visibility=np.ones(BODY_LANDMARKS),
                              presence=np.ones(BODY_LANDMARKS), world=np.zeros((BODY_LANDMARKS, 3)), score=1.0,
                              next_region=region, segmentation=np.zeros((LANDMARK_SIZE, LANDMARK_SIZE)), region=region)
    mask = np.zeros(SIZE, bool)
    x0, y0, x1, y1 = np.round(box).astype(int)
    mask[y0:y1, x0:x1] = True
    keypoints = np.concatenate([np.tile([x, 60.0], (17, 1)), np.ones((17, 1))], 1)
    return Observation(landmarks, mask.astype(np.float32), mask, box, look, 1.0, keypoints, body=mask)


@pytest.fixture
def tracker() -> Tracker:
    tracker = Tracker.__new__(Tracker)
    tracker.config = replace(load_ingest_config(), keypoint_crop_shifts=[])  # no model to take the keypoints again
    tracker.pose, tracker.plate, tracker.tracks = None, None, []
    return tracker


def _seen_at_0_then_again_at_4(tracker: Tracker, look: np.ndarray) -> tuple[Track, Observation, dict]:
    """A track seen at frame 0 (box centred at x = 100), missed in frames 1-3, seen again at frame 4 (x = 140);
    returns it, frame 4's observation and the gaps that were open before frame 4."""
    first = _observation(100.0, look)
    track = Track(0, first.landmarks, look.copy())
    tracker.tracks = [track]
    tracker._update(track, first, 0)
    track.missing = 3
    gaps = open_gaps(tracker.tracks, tracker.config.track_backfill_frames)
    again = _observation(140.0, look)
    tracker._update(track, again, 4)
    return track, again, gaps


def test_a_gap_is_looked_at_backwards_between_the_boxes_and_filled_in_frame_order(tracker, monkeypatch) -> None:
    look = np.full((2, 36), 1 / 36)
    track, again, gaps = _seen_at_0_then_again_at_4(tracker, look)
    assert set(gaps) == {0} and gaps[0].last_frame == 0
    looked: list[tuple[int, float]] = []

    def observe(self, image, region, original=None, covered=None):
        looked.append((int(image[0, 0, 0]), float(region.centre[0])))
        return _observation(float(region.centre[0]), look)

    monkeypatch.setattr(Tracker, "observe", observe)
    images = {f: np.full(SIZE + (3,), f, np.uint8) for f in (2, 3)}  # frame 1 is no longer held
    labels = {f: np.zeros(SIZE, np.uint16) for f in (1, 2, 3)}
    labels[2][:, 125:] = 7  # someone else holds the right part of frame 2, a quarter of what is found there
    filled = fill_gaps(tracker, gaps, [(track, again)], 4, images, lambda f: labels[f],
                       lambda f, new: labels.__setitem__(f, new))

    # frame 3 is 3/4 of the way from x = 100 to 140; frame 2 is 2/3 of the way from there to frame 3's find
    assert looked[0] == (3, pytest.approx(130.0))
    assert looked[1] == (2, pytest.approx(100.0 + 2 / 3 * 30.0))
    assert len(looked) == 2 and filled == [(0, 3), (0, 2)]
    assert track.frames == [0, 2, 3, 4] and track.looked_again == [3, 2] and track.boxes[2][0] == pytest.approx(120.0)
    assert track.missing == 0 and track.boxes[-1][0] == pytest.approx(130.0)  # the state is frame 4's
    assert (labels[3] == 1).sum() == again.mask.sum() and not labels[1].any()
    assert (labels[2][:, 125:] == 7).all() and (labels[2] == 1).sum() == 15 * BOX_HEIGHT  # only pixels nobody held


def test_someone_lying_on_the_others_or_looking_otherwise_is_not_taken(tracker, monkeypatch) -> None:
    look, other_look = np.full((2, 36), 1 / 36), np.zeros((2, 36))
    other_look[:, 0] = 1.0
    for found_look, others_column, taken in ((look, 150, True), (other_look, 150, False), (look, 0, False)):
        track, again, gaps = _seen_at_0_then_again_at_4(tracker, look)
        monkeypatch.setattr(Tracker, "observe",
                            lambda self, image, region, original=None, covered=None, found_look=found_look:
                            _observation(float(region.centre[0]), found_look))
        labels = {f: np.zeros(SIZE, np.uint16) for f in (1, 2, 3)}
        for frame in labels:
            labels[frame][:, others_column:] = 7  # from column 0: someone else holds the whole frame
        images = {f: np.zeros(SIZE + (3,), np.uint8) for f in (1, 2, 3)}
        filled = fill_gaps(tracker, gaps, [(track, again)], 4, images, lambda f: labels[f],
                           lambda f, new: labels.__setitem__(f, new))
        assert (len(filled) == 3) == taken and (track.frames == [0, 1, 2, 3, 4]) == taken
        assert taken or track.frames == [0, 4]


def test_someone_found_mostly_on_the_others_keeps_the_frame_but_not_the_keypoints(tracker, monkeypatch) -> None:
    look = np.full((2, 36), 1 / 36)
    track, again, gaps = _seen_at_0_then_again_at_4(tracker, look)
    monkeypatch.setattr(Tracker, "observe", lambda self, image, region, original=None, covered=None:
                        _observation(float(region.centre[0]), look))
    labels = {f: np.zeros(SIZE, np.uint16) for f in (2, 3)}
    for frame in labels:
        labels[frame][:, 128:] = 7  # frame 3's find (columns 120-139) lies 60% on someone else, frame 2's (110-129) 10%
    images = {f: np.zeros(SIZE + (3,), np.uint8) for f in (2, 3)}
    assert tracker.config.track_backfill_keypoints_max_overlap < 0.6 < tracker.config.track_behind_max_overlap
    filled = fill_gaps(tracker, gaps, [(track, again)], 4, images, lambda f: labels[f],
                       lambda f, new: labels.__setitem__(f, new))
    assert filled == [(0, 3), (0, 2)] and track.frames == [0, 2, 3, 4]
    assert (track.keypoints[2][:, 2] == 0).all() and (track.keypoints[2][:, :2] == 0).all()  # frame 3: not seen
    assert (track.keypoints[1][:, 2] == 1).all()  # frame 2 keeps its keypoints
    assert (labels[3] == 1).sum() == 8 * BOX_HEIGHT  # frame 3 still gets the pixels nobody held


def test_only_tracks_missing_at_most_the_backfill_frames_have_an_open_gap(tracker) -> None:
    look = np.full((2, 36), 1 / 36)
    tracks = []
    for index, missing in enumerate((0, 1, 15, 16)):
        track = Track(index, _observation(100.0, look).landmarks, look.copy())
        tracker._update(track, _observation(100.0, look), 0)
        track.missing = missing
        tracks.append(track)
    assert set(open_gaps(tracks, 15)) == {1, 2}
    assert open_gaps(tracks, 0) == {}


def test_a_track_started_late_looks_back_until_a_frame_without_its_person(tracker, monkeypatch) -> None:
    look = np.full((2, 36), 1 / 36)
    started = _observation(140.0, look)
    track = Track(0, started.landmarks, look.copy())
    tracker.tracks = [track]
    tracker._update(track, started, 5)
    looked: list[tuple[int, float]] = []

    def observe(self, image, region, original=None, covered=None):  # the person walks 10 px right a frame
        frame = int(image[0, 0, 0])
        looked.append((frame, float(region.centre[0])))
        return _observation(140.0 - 10.0 * (5 - frame), look) if frame >= 3 else None

    monkeypatch.setattr(Tracker, "observe", observe)
    images = {f: np.full(SIZE + (3,), f, np.uint8) for f in (1, 2, 3, 4)}
    labels = {f: np.zeros(SIZE, np.uint16) for f in images}
    filled = look_before_start(tracker, [track], 5, images, lambda f: labels[f],
                               lambda f, new: labels.__setitem__(f, new))
    # each frame in the region around the box found in the frame after; stops at frame 2, where nobody is
    assert looked == [(4, pytest.approx(140.0)), (3, pytest.approx(130.0)), (2, pytest.approx(120.0))]
    assert filled == [(0, 4), (0, 3)] and track.frames == [3, 4, 5] and track.looked_again == [4, 3]
    assert (labels[3] == 1).any() and not labels[2].any() and not labels[1].any()
