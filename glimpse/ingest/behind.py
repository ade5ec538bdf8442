"""Keypoints of a person behind someone, looked for again once tracking is done.

While a person passes behind someone nearer, the landmark model that follows them takes the nearer person's hips
and legs for theirs, and their region, re-centred on those, drifts (the `crouch` fixture, seed 1: 25-30 px low and
25% too large while the walker passes behind the crouching person); the written keypoints' runs there see the
wrong region, and the others are painted over by their masks of that moment. After tracking both ends of such a
passage are known, and every mask is final. Each run of frames where a person is behind someone (:func:`covered`
by a nearer person's mask; nearer: glimpse.ingest.occlusion.feet_rows) with the ``keypoints_behind_after_frames``
after it (the region that followed them takes some frames to come back onto them), at most
``keypoints_behind_max_frames`` long, between two frames where their hips and shoulders were written
(:func:`behind_runs`), is looked at again: the region interpolated between those two frames'
(:func:`region_from_keypoints`), the others' final masks painted over as for the written keypoints, and the written
keypoints' runs made there (:meth:`glimpse.ingest.tracker.Tracker.keypoints_behind`); joints on anyone else's pixels
are written as not seen (in those frames the person is behind someone).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from glimpse.ingest.blazepose import REGION_GROW
from glimpse.ingest.config import IngestConfig
from glimpse.ingest.crop import Region, region_from_alignment
from glimpse.ingest.occlusion import feet_rows
from glimpse.ingest.report import PersonTrack
from glimpse.ingest.sides import HIPS, SHOULDERS

# The top of the head (or a raised hand's end) from the mid hip, per the farthest COCO-17 point from it: COCO-17 has
# no point on the top of the head, which MediaPipe's alignment reaches.
HEAD_TOP_REACH = 1.15


def region_from_keypoints(points: np.ndarray, seen: np.ndarray, grow: float) -> Region | None:
    """The landmark model's region for a person whose COCO-17 points [17, 2] (pixels) are known where ``seen`` [17]
    bool, as MediaPipe's alignment places it: centred on the mid hip, the mid shoulder up, its half side the
    farthest seen point's distance from the mid hip times HEAD_TOP_REACH, grown by ``grow``. None without both hips
    and both shoulders."""
    torso = list(HIPS) + list(SHOULDERS)
    if not seen[torso].all():
        return None
    hips, shoulders = points[list(HIPS)].mean(0), points[list(SHOULDERS)].mean(0)
    up = (shoulders - hips) / max(float(np.linalg.norm(shoulders - hips)), 1e-6)
    reach = float(np.linalg.norm(points[seen] - hips, axis=1).max()) * HEAD_TOP_REACH
    return region_from_alignment(hips, hips + up * reach, grow)


def interpolated_region(before: Region, after: Region, fraction: float) -> Region:
    """The region ``fraction`` (0 .. 1) of the way from ``before`` to ``after``: centre and side linearly, the
    rotation along the shorter arc."""
    turn = np.arctan2(np.sin(after.angle - before.angle), np.cos(after.angle - before.angle))
    return Region(before.centre + fraction * (after.centre - before.centre),
                  before.side + fraction * (after.side - before.side), float(before.angle + fraction * turn))


def box_counts(mine: np.ndarray, others: list[np.ndarray]) -> tuple[int, list[int]]:
    """(the area of ``mine`` [H, W] bool, per mask of ``others`` how many of its pixels lie in the box of ``mine``):
    what :func:`covered` decides on. (0, zeros) for an empty ``mine``."""
    if not mine.any():
        return 0, [0] * len(others)
    rows, columns = np.nonzero(mine.any(1))[0], np.nonzero(mine.any(0))[0]
    inside = (slice(rows[0], rows[-1] + 1), slice(columns[0], columns[-1] + 1))
    return int(mine.sum()), [int(theirs[inside].sum()) for theirs in others]


def covered(area: int, nearer_in_box: list[int], min_cover: float) -> bool:
    """Whether a person whose mask has ``area`` pixels is behind someone: the box of their mask holds, of one of the
    nearer people's masks (``nearer_in_box``: their pixels there, :func:`box_counts`), at least ``min_cover`` times
    that area. Never for an empty mask."""
    return area > 0 and any(count >= min_cover * area for count in nearer_in_box)


def behind_runs(frames: list[int], covered_frames: set[int], ends: set[int], max_frames: int, after_frames: int = 0
                ) -> list[tuple[int, int]]:
    """(first, last) frame ids of the runs to look at again: each run of consecutive ``frames`` (sorted ids) that are
    behind someone (in ``covered_frames``, or within ``after_frames`` after one of those: the region that followed
    the person comes back onto them some frames after they come out from behind) or not in ``ends`` (frames with a
    region to start from: hips and shoulders written; a frame without one next to covered frames, often found by a
    mask alone, is looked at too), holding at least one frame behind someone, at most ``max_frames`` long, whose
    frames just before and just after are the person's and in ``ends``."""
    present = set(frames)
    behind = covered_frames | {frame_id + step for frame_id in covered_frames for step in range(1, after_frames + 1)}
    candidates = {frame_id for frame_id in frames if frame_id in behind or frame_id not in ends}
    runs = []
    start = None
    for frame_id in frames:
        if frame_id not in candidates:
            continue
        start = frame_id if start is None else start
        if frame_id + 1 not in candidates or frame_id + 1 not in present:
            if (behind & set(range(start, frame_id + 1)) and frame_id - start + 1 <= max_frames
                    and {start - 1, frame_id + 1} <= present & ends):
                runs.append((start, frame_id))
            start = None
    return runs


def behind_plan(people: list[PersonTrack], labels_of: Callable[[int], np.ndarray],
                to_tracking: Callable[[np.ndarray], np.ndarray], config: IngestConfig
                ) -> dict[int, list[tuple[int, Region]]]:
    """Frame id -> [(index into ``people``, region at the tracking size)]: the frames of each person's runs behind
    someone (:func:`behind_runs`; behind: :func:`covered` by the masks of the people whose feet are lower,
    glimpse.ingest.occlusion.feet_rows over ``mask_depth_frames``) and the region interpolated there between the
    run's two ends (:func:`region_from_keypoints` of the person's written keypoints, scene pixels, taken to the
    tracking size by ``to_tracking``). ``labels_of(frame id)``: the final tracking-size labels (each person's
    ``label``)."""
    present: dict[int, list[int]] = {}
    for index, person in enumerate(people):
        for frame_id in person.frames:
            present.setdefault(frame_id, []).append(index)
    bottoms: list[dict[int, float]] = [{} for _ in people]
    in_box: dict[tuple[int, int], tuple[int, dict[int, int]]] = {}  # (index, frame id) -> box_counts, by other
    for frame_id, here in present.items():  # each frame's labels read once: who is nearer needs the frames after
        labels = labels_of(frame_id)
        masks = {index: labels == people[index].label for index in here}
        for index in here:
            rows = np.nonzero(masks[index].any(1))[0]
            if len(rows):
                bottoms[index][frame_id] = float(rows[-1])
            if len(here) > 1:
                others = [other for other in here if other != index]
                area, counts = box_counts(masks[index], [masks[other] for other in others])
                in_box[index, frame_id] = area, dict(zip(others, counts))
    behind: list[set[int]] = [set() for _ in people]
    for frame_id, here in present.items():
        if len(here) < 2:
            continue
        feet = {index: feet_rows(bottoms[index], frame_id, config.mask_depth_frames) for index in here}
        for index in here:
            if feet[index] is None:
                continue
            area, counts = in_box[index, frame_id]
            nearer = [counts[other] for other in here
                      if other != index and feet[other] is not None and feet[other] > feet[index]]
            if nearer and covered(area, nearer, config.keypoints_behind_min_cover):
                behind[index].add(frame_id)
    plan: dict[int, list[tuple[int, Region]]] = {}
    for index, person in enumerate(people):
        rows = {frame_id: k for k, frame_id in enumerate(person.frames)}
        regions = {}
        for frame_id, k in rows.items():
            seen = person.keypoints[k, :, 2] > 0
            region = region_from_keypoints(to_tracking(person.keypoints[k, :, :2]), seen, REGION_GROW)
            if region is not None:
                regions[frame_id] = region
        for first, last in behind_runs(person.frames, behind[index], set(regions), config.keypoints_behind_max_frames,
                                       config.keypoints_behind_after_frames):
            before, after = regions[first - 1], regions[last + 1]
            for frame_id in range(first, last + 1):
                fraction = (frame_id - first + 1) / (last - first + 2)
                plan.setdefault(frame_id, []).append((index, interpolated_region(before, after, fraction)))
    return plan


def with_keypoints(person: PersonTrack, frame_id: int, keypoints: np.ndarray, relative3d: np.ndarray
                   ) -> PersonTrack:
    """``person`` with one frame's keypoints [17, 3] (scene pixels, confidence) and 3D points [17, 4] replaced, the
    frame listed in ``keypoints_behind``."""
    row = person.frames.index(frame_id)
    new_keypoints, new_relative3d = person.keypoints.copy(), person.relative3d.copy()
    new_keypoints[row], new_relative3d[row] = keypoints, relative3d
    return replace(person, keypoints=new_keypoints, relative3d=new_relative3d,
                   keypoints_behind=sorted({*person.keypoints_behind, frame_id}))
