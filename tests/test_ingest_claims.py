"""Who gets a person two tracks could claim (when several look behind the people found, when a lost track finds
someone in its old region), which observations a track's appearance follows, and which finds in the foreground are
kept. The landmark model is not run: the rules are what is tested; the whole ingest runs on rendered videos in
test_ingest.py."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from glimpse.ingest.appearance import appearance_distance
from glimpse.ingest.blazepose import BODY_LANDMARKS, LANDMARK_SIZE, REGION_GROW, PoseLandmarks
from glimpse.ingest.claims import drop_lookalikes, return_refound
from glimpse.ingest.config import load_ingest_config
from glimpse.ingest.crop import Region
from glimpse.ingest.observation import Observation, Track, observed_skeleton_distance
from glimpse.ingest.tracker import STILL_WIDTH, Tracker

BOX_HEIGHT = 80.0


def _look(red: float) -> np.ndarray:
    """An appearance (two halves of 4 bins) whose share of the first bin is ``red``."""
    half = np.array([red, 1.0 - red, 0.0, 0.0])
    return np.stack([half, half])


def _observation(x: float, red: float) -> Observation:
    """A standing person centred at column x (every landmark spread over a 2:1 box) who looks ``red``."""
    points = np.stack([np.full(BODY_LANDMARKS, x) + np.linspace(-10.0, 10.0, BODY_LANDMARKS),
                       np.linspace(20.0, 20.0 + BOX_HEIGHT, BODY_LANDMARKS)], 1)
    region = Region(np.array([x, 60.0]), BOX_HEIGHT * REGION_GROW, 0.0)
    landmarks = PoseLandmarks(points=points, visibility=np.ones(BODY_LANDMARKS), presence=np.ones(BODY_LANDMARKS),
                              world=np.zeros((BODY_LANDMARKS, 3)), score=1.0, next_region=region,
                              segmentation=np.zeros((LANDMARK_SIZE, LANDMARK_SIZE)), region=region)
    keypoints = np.concatenate([points[:17], np.ones((17, 1))], 1)
    return Observation(landmarks, None, None, np.array([x - 10.0, 20.0, x + 10.0, 20.0 + BOX_HEIGHT]), _look(red),
                       1.0, keypoints)


@pytest.fixture
def tracker() -> Tracker:
    tracker = Tracker.__new__(Tracker)
    tracker.config = load_ingest_config()
    tracker.pose, tracker.plate, tracker.tracks = None, None, []
    return tracker


def _track(index: int, x: float, red: float, missing: int = 0) -> Track:
    return Track(index, _observation(x, red).landmarks, _look(red), missing=missing)


@pytest.mark.parametrize("order", [(0, 1), (1, 0)])
def test_a_person_found_behind_by_the_wrong_track_first_is_taken_back_by_their_own(
        tracker: Tracker, order: tuple[int, int]) -> None:
    """A walker passes in front of someone who stands behind the people followed; both tracks' regions lie over
    the walker. Looking behind, a track finds the walker unless the walker is painted over (found already), then
    the person standing; it keeps what it finds when that looks like it within the follow distance. Whichever
    track looks first, the walker's track ends with the walker and the other with the person standing: the
    standing person's track (looks 0.40 from the walker) may take the walker first, and loses them to the walker's
    own (0.0 from them), then looks again and finds the person standing (0.29); the walker's track never keeps
    the person standing (0.67)."""
    walker_track, standing_track = _track(0, 100.0, 1.0), _track(1, 110.0, 0.7)
    tracker.tracks = [walker_track, standing_track]
    walker, standing = _observation(104.0, 1.0), _observation(112.0, 0.3)
    limit = tracker.config.track_follow_max_distance
    assert appearance_distance(walker_track.look, standing.look) > limit
    assert appearance_distance(standing_track.look, walker.look) <= limit
    assert appearance_distance(standing_track.look, standing.look) <= limit
    looks: list[int] = []

    def look_behind(image: np.ndarray, followed: dict[int, Observation], track: Track) -> Observation | None:
        looks.append(track.index)
        candidate = standing if any(o is walker for o in followed.values()) else walker
        return candidate if appearance_distance(track.look, candidate.look) <= limit else None

    tracker._look_behind = look_behind
    followed: dict[int, Observation] = {}
    tracker._look_behind_all(np.zeros((1, 1, 3)), followed, [tracker.tracks[i] for i in order])
    assert sorted(followed) == [0, 1] and followed[0] is walker and followed[1] is standing
    # the walker's track looking first: one look each; else the taking back costs two looks more
    assert looks == ([0, 1] if order == (0, 1) else [1, 0, 0, 1])


@pytest.mark.parametrize("case", ["returned", "other region", "no better", "other also missing", "other found"])
def test_whom_a_lost_track_finds_in_its_old_region_goes_to_the_track_they_look_like(tracker: Tracker,
                                                                                   case: str) -> None:
    """A track missing for two frames finds, in the region where its person was last seen, someone who looks 0.41
    from it (within the follow distance); a track seen in the last frame (0.28 from them), whose region lies over them
    too, found nobody. The person goes to that track, as they look like it better by more than the reclaim
    margin, and stays with the lost track when the other's region lies elsewhere, it looks no better, it was
    missing too, or it found someone itself."""
    lost, own = _track(0, 100.0, 0.3, missing=2), _track(1, 110.0 if case != "other region" else 300.0, 1.0)
    if case == "no better":
        own.look = _look(0.3)
    if case == "other also missing":
        own.missing = 1
    person = _observation(106.0, 0.85)
    assert appearance_distance(lost.look, person.look) <= tracker.config.track_follow_max_distance
    followed = {0: person} if case != "other found" else {0: person, 1: _observation(112.0, 1.0)}
    before = dict(followed)
    return_refound(followed, [lost, own], tracker.config.track_reclaim_margin)
    assert followed == ({1: person} if case == "returned" else before)


@pytest.mark.parametrize("case", ["dropped", "other region", "no better", "its own look"])
def test_a_find_that_looks_like_another_track_is_not_kept(tracker: Tracker, case: str) -> None:
    """A track's region slid half onto someone else: what it finds looks 0.41 from it (within the follow distance)
    but 0.28 from another live track (missing this frame: its person is hidden), whose predicted region lies over
    the find. The find is dropped (the track will look behind the people found), and kept when the other track's
    region lies elsewhere, when the find looks no better like it than the margin, or when it looks like the track's
    own person."""
    track = _track(0, 100.0, 0.3)
    other = _track(1, 110.0 if case != "other region" else 300.0, 1.0, missing=1)
    if case == "no better":
        other.look = _look(0.3)
    find = _observation(106.0, 0.3 if case == "its own look" else 0.85)
    assert appearance_distance(track.look, find.look) <= tracker.config.track_follow_max_distance
    followed = {0: find}
    drop_lookalikes(followed, [track, other], tracker.config.track_reclaim_margin)
    assert followed == ({} if case == "dropped" else {0: find})


def test_two_finds_of_two_people_are_both_kept_with_one_look_each(tracker: Tracker) -> None:
    tracker.tracks = [_track(0, 100.0, 0.9), _track(1, 300.0, 0.2)]
    finds = {0: _observation(100.0, 0.9), 1: _observation(300.0, 0.2)}
    looks: list[int] = []

    def look_behind(image: np.ndarray, followed: dict[int, Observation], track: Track) -> Observation | None:
        looks.append(track.index)
        return finds[track.index]

    tracker._look_behind = look_behind
    followed: dict[int, Observation] = {}
    tracker._look_behind_all(np.zeros((1, 1, 3)), followed, tracker.tracks)
    assert sorted(followed) == [0, 1] and all(followed[i] is finds[i] for i in finds) and looks == [0, 1]


def test_a_fit_lying_on_someone_else_does_not_move_its_tracks_appearance(tracker: Tracker) -> None:
    """A track followed onto a fit that lies half on the person in front keeps its appearance (the fit's mixes
    both people's); a fit clear of the others moves it by ``appearance_update``."""
    def boxed(observation: Observation, x0: int, x1: int) -> Observation:
        mask = np.zeros((120, 400), bool)
        mask[20:100, x0:x1] = True
        observation.mask, observation.body = mask, mask
        return observation

    front = boxed(_observation(100.0, 0.2), 90, 110)
    half_on_front = boxed(_observation(105.0, 0.6), 100, 120)  # 10 of its 20 columns on the person in front
    clear = boxed(_observation(300.0, 0.6), 290, 310)
    assert not tracker._clear_of(half_on_front, [front]) and tracker._clear_of(clear, [front])
    assert tracker._clear_of(half_on_front, [])

    for observation, moves in ((half_on_front, False), (clear, True)):
        track = _track(0, observation.box[0] + 10.0, 1.0)
        tracker._update(track, observation, 3, tracker._clear_of(observation, [front]))
        assert track.frames == [3] and np.array_equal(track.look, _look(1.0)) != moves


class _RecordingModel:
    """A landmark model that records the images it is given and finds ``found`` in each."""

    def __init__(self, found: PoseLandmarks):
        self.found, self.images = found, []

    def landmarks(self, image: np.ndarray, region: Region, refine: bool = True, mirror: bool = False) -> PoseLandmarks:
        self.images.append(image)
        return self.found


def _on_canvas(observation: Observation, x0: int, x1: int) -> Observation:
    """The observation's mask and body: columns x0..x1 of rows 20..100 of a 120x400 black frame."""
    mask = np.zeros((120, 400), bool)
    mask[20:100, x0:x1] = True
    observation.mask, observation.body = mask, mask
    observation.image = np.zeros((120, 400, 3), np.uint8)
    return observation


def test_the_written_keypoints_see_the_other_people_painted_over(tracker: Tracker) -> None:
    """At a crossing the landmark runs that give a person's written keypoints see the other people found painted
    over by the plate where they are nearer to their own skeleton than to this person's; this person's own
    pixels stay, and the keypoints are the run's on the painted frame. Someone outside the person's region is
    not painted, and the model is not run again."""
    tracker.config = replace(tracker.config, keypoint_crop_shifts=[], keypoints_paint_others=True)
    tracker.plate = np.full((120, 400, 3), 255, np.uint8)
    person, beside = _on_canvas(_observation(100.0, 0.5), 90, 110), _on_canvas(_observation(150.0, 0.5), 140, 160)
    moved = replace(person.landmarks, points=person.landmarks.points + 3.0)
    tracker.model = _RecordingModel(moved)
    tracker.written_keypoints(person.image, person, [beside])
    (seen,) = tracker.model.images
    assert (seen[beside.mask] == 255).all() and (seen[person.mask] == 0).all()
    assert np.allclose(person.keypoints[:, :2], moved.coco17()[0])

    far = _on_canvas(_observation(330.0, 0.5), 320, 340)
    alone = _on_canvas(_observation(100.0, 0.5), 90, 110)
    before = alone.keypoints.copy()
    tracker.model = _RecordingModel(moved)
    tracker.written_keypoints(alone.image, alone, [far])
    assert tracker.model.images == [] and np.array_equal(alone.keypoints, before)


def test_someone_already_painted_over_where_a_person_was_found_is_not_taken_for_someone_standing_still(
        tracker: Tracker) -> None:
    """A person found behind another (the other painted over with the plate to find them) has that image as their
    own; painting the other again for the written keypoints, their pixels there show the plate already, which is
    not someone the plate holds (who is painted with the colour of their surroundings): the frame tells."""
    tracker.config = replace(tracker.config, keypoint_crop_shifts=[], keypoints_paint_others=True,
                             paint_still_with="surroundings")
    tracker.plate = np.full((120, 400, 3), 255, np.uint8)
    person, other = _on_canvas(_observation(100.0, 0.5), 90, 110), _on_canvas(_observation(150.0, 0.5), 140, 160)
    frame = person.image.copy()  # black: nobody there is in the plate
    person.image[other.mask] = 255  # found with the other painted over
    tracker.model = _RecordingModel(person.landmarks)
    tracker.written_keypoints(frame, person, [other])
    (seen,) = tracker.model.images
    assert (seen[other.mask] == 255).all() and (seen[person.mask] == 0).all()
    still = tracker._painted_over(person.image, other.mask)  # the image alone says: someone standing still
    assert (still[30:90, 145:155] < 255).all()  # (inside: the opening leaves the region's corners to the plate)


def test_the_written_keypoints_see_someone_who_stood_still_painted_with_the_plates_texture_from_beside_them(
        tracker: Tracker) -> None:
    """Someone the plate shows (they stood still) is painted for the written keypoints' runs as
    ``keypoints_paint_still_with`` says, for tracking as ``paint_still_with`` says: with beside and surroundings,
    the runs see the plate's texture from beside them, tracking a flat patch of the surroundings' colour."""
    tracker.config = replace(tracker.config, keypoint_crop_shifts=[], keypoints_paint_others=True,
                             paint_still_with="surroundings", keypoints_paint_still_with="beside")
    texture = np.zeros((120, 400, 3), np.uint8)
    texture[:, :, 0] = (np.arange(400) * 7 % 256)[None]  # says where each pixel came from
    texture[:, :, 1] = np.arange(120)[:, None]
    person, other = _on_canvas(_observation(100.0, 0.5), 90, 110), _on_canvas(_observation(150.0, 0.5), 140, 160)
    frame = texture.copy()
    frame[person.mask | other.mask] = (20, 200, 20)
    tracker.plate = frame.copy()  # both stood still all video
    person.image = frame.copy()
    tracker.model = _RecordingModel(person.landmarks)
    tracker.written_keypoints(frame, person, [other])
    (seen,) = tracker.model.images
    margin = round(STILL_WIDTH * 120)  # the tracker's margin
    # from one region's width (20 px) plus the margin to the left (both sides clear: a tie goes left)
    assert np.array_equal(seen[30:90, 145:155], texture[30:90, 125 - margin:135 - margin])
    assert (seen[person.mask] == (20, 200, 20)).all()
    tracked = tracker._painted_over(frame, other.mask)
    assert np.ptp(tracked[30:90, 145:155].reshape(-1, 3)[:, 0]) < np.ptp(seen[30:90, 145:155].reshape(-1, 3)[:, 0])


@pytest.mark.parametrize("in_front", [True, False])
def test_a_person_in_front_keeps_their_own_pixels_where_someone_behind_overlaps(tracker: Tracker,
                                                                                 in_front: bool) -> None:
    """Pixels on both people's bodies and nearer to the other's skeleton are painted for the person behind, whose
    view the other hides, and spared for the person in front, whose body they are; the other's pixels off this
    person's body are painted either way."""
    tracker.config = replace(tracker.config, keypoint_crop_shifts=[], keypoints_paint_others=True)
    tracker.plate = np.full((120, 400, 3), 255, np.uint8)
    person, other = _on_canvas(_observation(100.0, 0.5), 90, 140), _on_canvas(_observation(150.0, 0.5), 130, 160)
    tracker.model = _RecordingModel(person.landmarks)
    tracker.written_keypoints(person.image, person, [other], [in_front])
    (seen,) = tracker.model.images
    nearer_other = observed_skeleton_distance(other) <= observed_skeleton_distance(person)
    shared, only_other = person.mask & other.mask & nearer_other, other.mask & ~person.mask & nearer_other
    region = np.zeros_like(person.mask)
    x0, _, x1, _ = np.round(person.landmarks.region.box()).astype(int)
    region[:, max(x0, 0):x1] = True
    assert shared.any() and (only_other & region).any()
    assert (seen[only_other] == 255).all() and (seen[shared] == (0 if in_front else 255)).all()


@pytest.mark.parametrize("columns_changed, kept", [(0, False), (2, False), (6, True)])
def test_someone_found_in_the_foreground_must_in_part_differ_from_the_plate(tracker: Tracker, columns_changed: int,
                                                                           kept: bool) -> None:
    """A fit in a foreground region whose body the plate shows as the frame does (a painted pillar beside the person
    who made the foreground) is something the plate holds; it is kept when at least ``foreground_min_differing``
    (a fifth) of its body's pixels differ from the plate: here 0, 2 or 6 of its 20 columns."""
    tracker.plate = np.full((120, 400, 3), 90, np.uint8)
    found = _on_canvas(_observation(100.0, 0.5), 90, 110)
    image = tracker.plate.copy()
    image[20:100, 90:90 + columns_changed] = 250
    assert tracker._shown_by_plate(image, found) != kept
