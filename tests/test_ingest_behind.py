"""Keypoints of a person behind someone, looked for again after tracking (glimpse.ingest.behind): which frames,
which regions, what the runs there see and what is written. The landmark model is replaced by a stand-in, so the
rules are what is tested; the whole ingest runs on rendered videos in test_ingest.py."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from glimpse.ingest.behind import (HEAD_TOP_REACH, behind_plan, behind_runs, box_counts, covered, interpolated_region,
                                   region_from_keypoints, with_keypoints)
from glimpse.ingest.blazepose import REGION_GROW
from glimpse.ingest.config import load_ingest_config
from glimpse.ingest.crop import Region
from glimpse.ingest.occlusion import feet_rows
from glimpse.ingest.report import PersonTrack
from glimpse.ingest.tracker import Tracker

SIZE = (120, 200)  # H, W of the frames


def _upright(x: float, seen: np.ndarray | None = None) -> np.ndarray:
    """[17, 3] COCO-17 keypoints of an upright person centred at column x: eyes at row 18, shoulders at 40, hips at
    70, ankles at 130 (confidence 1, or 0 where ``seen`` is False)."""
    rows = {0: 20, 1: 18, 2: 18, 3: 20, 4: 20, 5: 40, 6: 40, 7: 55, 8: 55, 9: 70, 10: 70, 11: 70, 12: 70,
            13: 100, 14: 100, 15: 130, 16: 130}
    points = np.array([[x + (-5 if j % 2 else 5) * (j > 0), rows[j], 1.0] for j in range(17)])
    if seen is not None:
        points[~seen, 2] = 0.0
    return points


def test_the_region_is_centred_on_the_mid_hip_and_reaches_the_farthest_seen_point() -> None:
    points = _upright(100.0)
    region = region_from_keypoints(points[:, :2], points[:, 2] > 0, REGION_GROW)
    assert region.centre == pytest.approx([100.0, 70.0])
    assert region.angle == pytest.approx(0.0, abs=1e-9)  # upright: the shoulders straight above the hips
    farthest = np.hypot(5.0, 60.0)  # an ankle
    assert region.side == pytest.approx(2 * farthest * HEAD_TOP_REACH * REGION_GROW)
    no_legs = np.arange(17) < 13
    region = region_from_keypoints(points[:, :2], no_legs, REGION_GROW)
    assert region.side == pytest.approx(2 * np.hypot(5.0, 52.0) * HEAD_TOP_REACH * REGION_GROW)  # an eye
    assert region_from_keypoints(points[:, :2], np.arange(17) != 11, REGION_GROW) is None  # a hip unseen


def test_the_region_between_two_is_interpolated_along_the_shorter_turn() -> None:
    before = Region(np.array([10.0, 20.0]), 100.0, 3.0)
    after = Region(np.array([30.0, 20.0]), 140.0, -3.0)
    halfway = interpolated_region(before, after, 0.5)
    assert halfway.centre == pytest.approx([20.0, 20.0]) and halfway.side == pytest.approx(120.0)
    assert abs(np.cos(halfway.angle) - (-1.0)) < 1e-9  # through pi, not through 0


def test_covered_counts_a_nearer_persons_pixels_inside_the_box_of_the_mask() -> None:
    mine = np.zeros(SIZE, bool)
    mine[20:100, 50:70] = True  # 1600 px, its box 80 x 20
    inside, outside = np.zeros(SIZE, bool), np.zeros(SIZE, bool)
    inside[60:100, 40:60] = True  # 400 px in the box (10 columns of it): 0.25 of mine
    outside[20:100, 100:140] = True
    area, (in_box, out_of_box) = box_counts(mine, [inside, outside])
    assert area == 1600 and in_box == 400 and out_of_box == 0
    assert covered(area, [in_box], 0.25) and not covered(area, [in_box], 0.3)
    assert not covered(area, [out_of_box], 0.01)
    assert box_counts(np.zeros(SIZE, bool), [inside]) == (0, [0]) and not covered(0, [0], 0.0)


def test_the_feet_row_is_a_median_over_the_window() -> None:
    bottoms = {0: 100.0, 1: 102.0, 2: 140.0, 3: 101.0, 9: 50.0}
    assert feet_rows(bottoms, 1, 2) == pytest.approx(101.5)  # frames 0-3: the median shrugs off frame 2
    assert feet_rows(bottoms, 6, 1) is None


@pytest.mark.parametrize("covered_frames, ends, frames, runs", [
    ({5, 6, 7}, set(range(21)), list(range(21)), [(5, 7)]),
    ({5, 6, 7, 8}, set(range(21)), list(range(21)), []),  # longer than 3
    ({0, 1}, set(range(21)), list(range(21)), []),  # no frame before
    ({5, 6}, set(range(21)) - {7}, list(range(21)), [(5, 7)]),  # frame 7 has no region: looked at too, to 8
    ({5, 6}, set(range(21)) - {7, 8}, list(range(21)), []),  # ... but frames 5-8 are over 3
    ({5}, set(range(21)) - {10}, list(range(21)), [(5, 5)]),  # frame 10 without a region, not next to a run: left
    ({5, 7}, set(range(21)), [f for f in range(21) if f != 6], []),  # frame 6 is not the person's
    ({5, 10, 11}, set(range(21)), list(range(21)), [(5, 5), (10, 11)]),
])
def test_runs_behind_someone_need_a_region_on_both_sides(covered_frames, ends, frames, runs) -> None:
    assert behind_runs(frames, covered_frames, ends, 3) == runs


@pytest.mark.parametrize("covered_frames, frames, after, runs", [
    ({5, 6}, list(range(21)), 2, [(5, 8)]),  # the two frames after the last covered one too
    ({5, 6}, list(range(21)), 0, [(5, 6)]),
    ({5, 9}, list(range(21)), 3, [(5, 12)]),  # frames 6-8 join the two covered frames into one run
    ({5, 6}, [f for f in range(21) if f != 8], 2, []),  # frame 8 is not the person's: no frame to end at
    ({5, 6}, list(range(21)), 8, []),  # 5-14 is longer than max_frames
])
def test_runs_behind_someone_go_on_for_the_frames_after(covered_frames, frames, after, runs) -> None:
    assert behind_runs(frames, covered_frames, set(frames), 9, after) == runs


def _person(pid: str, label: int, frames: list[int], keypoints: np.ndarray) -> PersonTrack:
    count = len(frames)
    return PersonTrack(pid, label, frames, keypoints, np.zeros((count, 17, 4)), np.zeros((count, 4)), [], [])


def test_the_plan_interpolates_the_region_of_the_person_behind_between_the_frames_around() -> None:
    """Person 1 (feet at row 80) walks right from x = 40 behind person 2 (feet at row 110), who stands in front of
    their middle in frames 3-5; with the frame after those (keypoints_behind_after_frames), person 1's keypoints in
    frames 2 and 7 give the regions the plan interpolates."""
    config = replace(load_ingest_config(), keypoints_behind_min_cover=0.25, keypoints_behind_max_frames=30,
                     keypoints_behind_after_frames=1, mask_depth_frames=2)
    frames = list(range(9))
    walker = _person("p0", 1, frames, np.stack([_upright(40.0 + 10 * f) for f in frames]))
    front = _person("p1", 2, frames, np.stack([_upright(100.0) for _ in frames]))

    def labels_of(frame_id: int) -> np.ndarray:
        labels = np.zeros(SIZE, np.uint16)
        x = 40 + 10 * frame_id
        labels[20:80, x - 8:x + 8] = 1
        if 3 <= frame_id <= 5:
            labels[10:110, x - 3:x + 3] = 2  # 360 of the box's px, the walker keeps 600: over 0.25
        else:
            labels[10:110, 180:190] = 2  # elsewhere: not over the walker
        return labels

    plan = behind_plan([walker, front], labels_of, lambda points: points, config)
    assert sorted(plan) == [3, 4, 5, 6] and all(len(plan[f]) == 1 and plan[f][0][0] == 0 for f in plan)
    before = region_from_keypoints(walker.keypoints[2, :, :2], np.ones(17, bool), REGION_GROW)
    after = region_from_keypoints(walker.keypoints[7, :, :2], np.ones(17, bool), REGION_GROW)
    assert plan[3][0][1].centre == pytest.approx(before.centre + (after.centre - before.centre) / 5)
    assert plan[6][0][1].centre == pytest.approx(before.centre + (after.centre - before.centre) * 4 / 5)


def test_a_person_in_front_is_not_planned_for() -> None:
    """In frames 3-5 the far person's pixels (feet higher up) lie inside the near person's box, over the cover: the
    near person is not behind them, and nothing is planned."""
    config = replace(load_ingest_config(), keypoints_behind_min_cover=0.25, mask_depth_frames=2)
    frames = list(range(9))
    near = _person("p0", 1, frames, np.stack([_upright(100.0) for _ in frames]))
    far = _person("p1", 2, frames, np.stack([_upright(100.0) for _ in frames]))

    def labels_of(frame_id: int) -> np.ndarray:
        labels = np.zeros(SIZE, np.uint16)
        labels[40:115, 80:120] = 1
        if 3 <= frame_id <= 5:
            labels[30:70, 90:110] = 2  # 600 px in the near person's box, who keeps 2400
        else:
            labels[30:70, 150:170] = 2
        return labels

    assert behind_plan([near, far], labels_of, lambda points: points, config) == {}


def test_with_keypoints_replaces_one_frame_and_lists_it() -> None:
    person = _person("p0", 1, [3, 4, 5], np.zeros((3, 17, 3)))
    new = with_keypoints(person, 4, np.ones((17, 3)), np.full((17, 4), 2.0))
    assert (new.keypoints[1] == 1).all() and not new.keypoints[[0, 2]].any() and (new.relative3d[1] == 2).all()
    assert new.keypoints_behind == [4] and not person.keypoints.any()


def test_the_runs_behind_see_the_others_painted_and_hide_joints_on_them(monkeypatch) -> None:
    """The landmark runs are made on the frame with every other person's pixels painted (here with the colour of
    their surroundings: no plate), in the planned region; a joint on another person's pixels is written as not seen."""
    tracker = Tracker.__new__(Tracker)
    tracker.config = replace(load_ingest_config(), keypoint_crop_shifts=[])
    tracker.pose, tracker.plate, tracker.tracks = None, None, []
    image = np.full(SIZE + (3,), 90, np.uint8)
    labels = np.zeros(SIZE, np.uint16)
    labels[20:100, 40:60] = 1
    labels[20:100, 60:80] = 2
    image[labels == 2] = (250, 0, 0)
    seen: dict = {}

    class Found:
        keypoints = np.concatenate([np.tile([[50.0, 50.0]], (17, 1)), np.ones((17, 1))], 1)
        keypoints[3, :2] = (70.0, 50.0)  # on person 2
        relative3d = np.ones((17, 3))

    def observe(self, painted, region, original=None, covered=None):
        seen["image"], seen["region"] = painted, region
        return Found()

    monkeypatch.setattr(Tracker, "observe", observe)
    monkeypatch.setattr(Tracker, "written_keypoints", lambda self, image, observation, *rest: None)
    region = Region(np.array([50.0, 60.0]), 100.0, 0.0)
    keypoints, relative3d = tracker.keypoints_behind(image, labels, 1, region)
    assert seen["region"] is region
    # the other person painted with the grey around them (to rounding), the person's own pixels as they were
    assert np.abs(seen["image"][labels == 2].astype(int) - 90).max() <= 1 and (seen["image"][labels == 1] == 90).all()
    assert keypoints[3, 2] == 0 and (keypoints[3, :2] == 0).all() and relative3d[3, 3] == 0
    assert (keypoints[np.arange(17) != 3, 2] == 1).all() and (relative3d[np.arange(17) != 3, :3] == 1).all()
