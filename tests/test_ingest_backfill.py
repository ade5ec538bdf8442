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
from glimpse.ingest.observation import Observation, Track, skeleton_distance
from glimpse.ingest.tracker import Tracker

SIZE = (120, 200)  # H, W of the frames
BOX_HEIGHT = 60.0
# the stand-in's skeleton: (landmarks, column from the box's centre, row): head, shoulders, arms, hips, legs. Its
# torso is 20 px long, so the pixels within mask_body_radius (0.25 torso lengths) of it lie within 5 px.
STICK = ((range(11), 0, 38), ((11,), -6, 45), ((12,), 6, 45), ((13, 15, 17, 19, 21), -8, 58),
         ((14, 16, 18, 20, 22), 8, 58), ((23,), -5, 65), ((24,), 5, 65), ((25, 27, 29, 31), -4, 85),
         ((26, 28, 30, 32), 4, 85))


def _box_at(x: float) -> np.ndarray:
    return np.array([x - 10.0, 30.0, x + 10.0, 30.0 + BOX_HEIGHT])


def _stick_at(x: float) -> np.ndarray:
    """[33, 2] the stand-in skeleton's landmarks, centred at column x."""
    points = np.zeros((BODY_LANDMARKS, 2))
    for indices, column, row in STICK:
        points[list(indices)] = (x + column, row)
    return points


def _box_mask(x: float) -> np.ndarray:
    """[H, W] bool: the pixels of the box centred at column x."""
    mask = np.zeros(SIZE, bool)
    x0, y0, x1, y1 = np.round(_box_at(x)).astype(int)
    mask[y0:y1, x0:x1] = True
    return mask


def _observation(x: float, look: np.ndarray) -> Observation:
    """A person whose box is centred at column x; their mask and body: the box's pixels."""
    box = _box_at(x)
    region = Region(np.array([x, 60.0]), BOX_HEIGHT * REGION_GROW, 0.0)
    landmarks = PoseLandmarks(points=_stick_at(x), visibility=np.ones(BODY_LANDMARKS),
                              presence=np.ones(BODY_LANDMARKS), world=np.zeros((BODY_LANDMARKS, 3)), score=1.0,
                              next_region=region, segmentation=np.zeros((LANDMARK_SIZE, LANDMARK_SIZE)), region=region)
    mask = _box_mask(x)
    keypoints = np.concatenate([np.tile([x, 60.0], (17, 1)), np.ones((17, 1))], 1)
    return Observation(landmarks, mask.astype(np.float32), mask, box, look, 1.0, keypoints, body=mask)


def _near_stick(x: float, radius: float) -> np.ndarray:
    """[H, W] bool: the pixels within ``radius`` torso lengths of the stand-in skeleton centred at column x."""
    return skeleton_distance(_observation(x, np.zeros((2, 36))).landmarks, SIZE) < radius


def _finding_at_the_centre(look: np.ndarray, covered_seen: list[np.ndarray]):
    """A stand-in for Tracker.observe that finds a person at its region's centre and keeps each look's painted
    pixels in ``covered_seen``."""
    def observe(self, image, region, original=None, covered=None):
        covered_seen.append(covered.copy())
        return _observation(float(region.centre[0]), look)
    return observe


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
        # the model finds someone 15 px right of where the person was expected: off the pixels spared there
        monkeypatch.setattr(Tracker, "observe",
                            lambda self, image, region, original=None, covered=None, found_look=found_look:
                            _observation(float(region.centre[0]) + 15.0, found_look))
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


def test_where_nobody_is_found_the_others_are_painted_over_but_near_where_the_person_was_expected(
        tracker, monkeypatch) -> None:
    """A missed frame is looked at once more where the first look finds nobody, the others painted over but near
    where the person was expected there: a person the model fitted one skeleton over two people with holds the lost
    one's pixels in its labels."""
    look = np.full((2, 36), 1 / 36)
    track, again, gaps = _seen_at_0_then_again_at_4(tracker, look)
    covered_seen: list[np.ndarray] = []
    monkeypatch.setattr(Tracker, "observe", _finding_at_the_centre(look, covered_seen))
    labels = {3: np.zeros(SIZE, np.uint16)}
    labels[3][:, 100:] = 7  # the other person's labels cover the whole of where the lost one is (x = 130)
    theirs = labels[3] == 7
    images = {3: np.full(SIZE + (3,), 3, np.uint8)}
    filled = fill_gaps(tracker, gaps, [(track, again)], 4, images, lambda f: labels[f],
                       lambda f, new: labels.__setitem__(f, new))
    near = _near_stick(130.0, tracker.config.mask_body_radius)  # frame 4's skeleton moved to frame 3's box
    # first look: all of theirs painted over, and what is found lies on them; then all but near where expected
    assert len(covered_seen) == 2 and (covered_seen[0] == theirs).all() and (covered_seen[1] == theirs & ~near).all()
    assert filled == [(0, 3)] and (track.keypoints[track.frames.index(3)][:, 2] == 1).all()  # found, keypoints kept
    assert ((labels[3] == 1) == near & _box_mask(130.0)).all()  # it takes its body near where it was expected
    assert (labels[3][:, 145:] == 7).all() and (labels[3][:, 100:115] == 7).all()


@pytest.mark.parametrize("recorded_at, taken", [(170.0, True), (130.0, False)])
def test_the_second_look_does_not_take_someone_recorded_in_that_frame(tracker, monkeypatch, recorded_at: float,
                                                                     taken: bool) -> None:
    """With the others' pixels left near where the person was expected, the second look may find one of them."""
    look = np.full((2, 36), 1 / 36)
    track, again, gaps = _seen_at_0_then_again_at_4(tracker, look)
    other = Track(1, _observation(recorded_at, look).landmarks, look.copy())
    tracker._update(other, _observation(recorded_at, look), 3)
    tracker.tracks.append(other)
    monkeypatch.setattr(Tracker, "observe", lambda self, image, region, original=None, covered=None:
                        _observation(float(region.centre[0]), look))
    labels = {3: np.zeros(SIZE, np.uint16)}
    labels[3][:, 100:] = 2  # the other track's labels cover the whole of where this one's person is expected
    images = {3: np.full(SIZE + (3,), 3, np.uint8)}
    filled = fill_gaps(tracker, gaps, [(track, again)], 4, images, lambda f: labels[f],
                       lambda f, new: labels.__setitem__(f, new))
    assert (filled == [(0, 3)]) == taken and (3 in track.frames) == taken and (labels[3] == 1).any() == taken


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


def _started_at_5(tracker: Tracker, look: np.ndarray) -> Track:
    """The tracker's only track, started at frame 5 (box centred at x = 140)."""
    started = _observation(140.0, look)
    track = Track(0, started.landmarks, look.copy())
    tracker.tracks = [track]
    tracker._update(track, started, 5)
    return track


def test_a_track_started_late_looks_back_until_a_frame_without_its_person(tracker, monkeypatch) -> None:
    tracker.config = replace(tracker.config, track_look_back_misses=0)
    look = np.full((2, 36), 1 / 36)
    track = _started_at_5(tracker, look)
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


def test_a_track_started_late_does_not_look_a_second_time_past_the_others(tracker, monkeypatch) -> None:
    """Often a second track on someone followed: looking past them where they are would take their pixels."""
    look = np.full((2, 36), 1 / 36)
    track = _started_at_5(tracker, look)
    covered_seen: list[np.ndarray] = []
    monkeypatch.setattr(Tracker, "observe", _finding_at_the_centre(look, covered_seen))
    labels = {4: np.zeros(SIZE, np.uint16)}
    labels[4][:, 100:] = 7  # someone else holds all of where the track's person would be in frame 4
    images = {4: np.full(SIZE + (3,), 4, np.uint8)}
    filled = look_before_start(tracker, [track], 5, images, lambda f: labels[f],
                               lambda f, new: labels.__setitem__(f, new))
    assert len(covered_seen) == 1 and filled == [] and (labels[4][:, 100:] == 7).all()


@pytest.mark.parametrize("misses, frames", [(2, [0, 1, 4, 5]), (1, [4, 5])])
def test_a_track_started_late_looks_back_past_frames_where_its_person_was_hidden(tracker, monkeypatch, misses: int,
                                                                                 frames: list[int]) -> None:
    """Someone standing still whom a passer-by hid in frames 2-3: the look goes on past at most
    track_look_back_misses frames in a row without them, in the region of the last frame where they were found."""
    tracker.config = replace(tracker.config, track_look_back_misses=misses)
    look = np.full((2, 36), 1 / 36)
    track = _started_at_5(tracker, look)
    looked: list[tuple[int, float]] = []

    def observe(self, image, region, original=None, covered=None):
        frame = int(image[0, 0, 0])
        looked.append((frame, float(region.centre[0])))
        return None if frame in (2, 3) else _observation(140.0 - 2.0 * (5 - frame), look)

    monkeypatch.setattr(Tracker, "observe", observe)
    images = {f: np.full(SIZE + (3,), f, np.uint8) for f in range(5)}
    labels = {f: np.zeros(SIZE, np.uint16) for f in images}
    filled = look_before_start(tracker, [track], 5, images, lambda f: labels[f],
                               lambda f, new: labels.__setitem__(f, new))
    assert track.frames == frames and [f for _, f in filled] == frames[-2::-1]
    regions = {frame: centre for frame, centre in looked}
    assert regions[3] == pytest.approx(138.0) and regions[2] == pytest.approx(138.0)  # frame 4's find
    if misses == 2:
        assert regions[1] == pytest.approx(138.0) and regions[0] == pytest.approx(132.0) and (labels[1] == 1).any()
    else:
        assert 1 not in regions and not labels[1].any()
