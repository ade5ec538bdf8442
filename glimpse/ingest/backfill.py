"""Looking again at the frames a track missed, once it has found its person after them (and before a track's
first frame, for a person found late).

Following a person frame by frame only looks forward: where someone passes behind another person, their region is
extrapolated from before the gap, and once the model loses them (half hidden, an arm of the person in front across
them) they are found again only when a detector or the foreground brings them back, some frames later. Those frames
are the ones a reconstruction needs most. When a track sees its person again after missing at most
``track_backfill_frames`` frames, each missed frame still held is looked at again, backwards from where the person
is seen again: the region around the box between the person's boxes before the gap and at the next sighting
(interpolated over time; a frame filled is the next sighting for the one before it, as when a detector's box starts
a region), with the people found in that frame painted over, and where that finds nobody, once more with their
pixels near where the person was expected left (the model, losing someone behind another person, often fits one
skeleton over both, whose labels then hold the lost one's pixels). What is found there is kept only under the rules
of looking behind someone (mostly off the others' pixels, looking like the track as a re-identified person must);
it is given the pixels of its segmentation that nobody found in that frame holds (whoever a track lost was behind
them), and nothing is invented for frames where the person stays hidden. A track that starts late (someone
entering, first seen from behind, or standing where a passer-by hid them) looks back the same way, frame by frame,
past at most ``track_look_back_misses`` frames in a row without its person, with the first look only (often it is a
second track on someone followed).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from glimpse.ingest.blazepose import REGION_GROW, PoseLandmarks
from glimpse.ingest.crop import Region, box_centre, region_around_box
from glimpse.ingest.observation import Observation, Track, skeleton_distance
from glimpse.ingest.tracker import Tracker


@dataclass(frozen=True)
class Gap:
    """A track (by index, in :func:`open_gaps`' dict) that has not seen its person since ``last_frame``, where their
    landmarks' box was ``box`` (x0, y0, x1, y1, pixels)."""

    last_frame: int
    box: np.ndarray


def open_gaps(tracks: list[Track], max_frames: int) -> dict[int, Gap]:
    """Track index -> its gap, for the tracks that have missed their person in 1 to ``max_frames`` frames since
    they last saw them (call before :meth:`Tracker.step`)."""
    return {t.index: Gap(t.frames[-1], t.boxes[-1]) for t in tracks if t.frames and 0 < t.missing <= max_frames}


def fill_gaps(tracker: Tracker, gaps: dict[int, Gap], observed: list[tuple[Track, Observation]], frame_id: int,
              images: dict[int, np.ndarray], labels_of: Callable[[int], np.ndarray],
              write_labels: Callable[[int, np.ndarray], None]) -> list[tuple[int, int]]:
    """For every track of ``observed`` (:meth:`Tracker.step`'s result for ``frame_id``) that had a gap, look again
    at each missed frame held in ``images`` (frame id -> [H, W, 3] uint8 at the tracking size), backwards; a person
    found is recorded in the track and given the pixels of their segmentation no one holds in that frame's labels
    (``labels_of`` / ``write_labels``: [H, W] uint16, 0 = nobody, else 1 + track index). Returns (track index,
    frame id) of every frame filled."""
    filled = []
    for track, observation in observed:
        gap = gaps.get(track.index)
        if gap is None:
            continue
        later, later_frame = observation, frame_id  # the nearest later sighting
        for missed in range(frame_id - 1, gap.last_frame, -1):
            if missed not in images:
                continue
            weight = (missed - gap.last_frame) / (later_frame - gap.last_frame)
            box = (1 - weight) * gap.box + weight * later.box
            expected = later.landmarks.moved(box_centre(box) - box_centre(later.box))
            found = _look_again(tracker, track, missed, region_around_box(box, REGION_GROW), expected,
                                images[missed], labels_of, write_labels)
            if found is not None:
                later, later_frame = found, missed
                filled.append((track.index, missed))
    return filled


def look_before_start(tracker: Tracker, started: list[Track], frame_id: int, images: dict[int, np.ndarray],
                      labels_of: Callable[[int], np.ndarray],
                      write_labels: Callable[[int, np.ndarray], None]) -> list[tuple[int, int]]:
    """Every track ``started`` at ``frame_id`` looks back at the frames before it held in ``images``, each in the
    region around its box in the nearest later frame where it was found (a person moves little between two frames),
    until more than ``track_look_back_misses`` frames in a row without its person (found late: entering, first seen
    from behind, or standing where someone passing hid them). The rest as :func:`fill_gaps`."""
    filled = []
    for track in started:
        box, misses = track.boxes[0], 0
        for earlier in range(frame_id - 1, frame_id - 1 - len(images), -1):
            if earlier not in images:
                break
            found = _look_again(tracker, track, earlier, region_around_box(box, REGION_GROW), None, images[earlier],
                                labels_of, write_labels)
            if found is None:
                misses += 1
                if misses > tracker.config.track_look_back_misses:
                    break
                continue
            box, misses = found.box, 0
            filled.append((track.index, earlier))
    return filled


def _look_again(tracker: Tracker, track: Track, frame_id: int, region: Region, expected: PoseLandmarks | None,
                image: np.ndarray, labels_of: Callable[[int], np.ndarray],
                write_labels: Callable[[int, np.ndarray], None]) -> Observation | None:
    """:meth:`Tracker.look_again` for ``track`` in one earlier frame, the people of its labels painted over; what
    is found takes the pixels of its segmentation that nobody holds there. Where that finds nobody and the person
    is ``expected`` somewhere (a track that saw them before: landmarks, else None), once more with the others'
    pixels within ``mask_body_radius`` of that skeleton (if any) left as they are: the model, losing someone who
    passes behind another person, often fits one skeleton over both, and that person's labels then hold the lost
    one's pixels. What is found so must not be one of the people recorded in that frame (with their pixels left,
    it may be them), and it also takes those of their pixels on its body. Not for a track that starts late: often a
    second track on someone followed. Returns the observation or None."""
    labels = labels_of(frame_id)
    label = track.index + 1
    others = (labels != 0) & (labels != label)
    found = tracker.look_again(image, region, others, track, frame_id)
    if found is not None:
        taken = found.mask & (labels == 0)
    elif expected is None:
        return None
    else:
        spared = others & (skeleton_distance(expected, others.shape) < tracker.config.mask_body_radius)
        if not spared.any():
            return None
        recorded = [t.keypoints[t.frames.index(frame_id)] for t in tracker.tracks
                    if t is not track and frame_id in t.frames]
        found = tracker.look_again(image, region, others & ~spared, track, frame_id, recorded)
        if found is None:
            return None
        taken = found.mask & (labels == 0) | tracker.body_pixels(found) & spared
    labels = labels.copy()
    labels[taken] = label
    write_labels(frame_id, labels)
    return found
