"""Stage 01's camera-motion measure: the core's (glimpse.cameras.motion) on the scene's frames, with the
people's regions (masks or keypoint boxes) left out."""

from __future__ import annotations

from pathlib import Path

from glimpse.cameras.motion import MotionMeasure, measure_motion, sample_ids
from glimpse.sfm.frames import grey
from glimpse.sfm.person_regions import PersonRegions


def measure_camera_motion(
    frames: dict[int, Path], regions: PersonRegions, sample_frames: int, min_tracked_fraction: float
) -> MotionMeasure:
    ids = sorted(frames)
    if len(ids) < 2:
        return MotionMeasure(0.0, {}, 0)
    first = grey(frames[ids[0]])
    shape = first.shape
    later = ((fid, grey(frames[fid])) for fid in sample_ids(ids, sample_frames))
    return measure_motion(first, later, min_tracked_fraction,
                          lambda fid: regions.exclusion(ids[0] if fid is None else fid, shape))
