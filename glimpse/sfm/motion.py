"""Is the camera moving? Measured from the frames, outside the people.

Corners of the first frame (people excluded) are tracked into frames spread over
the video with pyramidal Lucas-Kanade; the camera's motion is the largest, over
those frames, of the median displacement of the tracked corners, as a fraction
of the image diagonal. Losing most corners also counts as large motion.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from glimpse.sfm.frames import grey
from glimpse.sfm.person_regions import PersonRegions

_MAX_CORNERS = 800
_CORNER_QUALITY = 0.01
_LK_WINDOW = (21, 21)
_LK_LEVELS = 4


@dataclass(frozen=True)
class MotionMeasure:
    """motion: largest median displacement / image diagonal; per_frame: frame id -> that ratio."""

    motion: float
    per_frame: dict[int, float]
    corners: int


def measure_camera_motion(
    frames: dict[int, Path], regions: PersonRegions, sample_frames: int, min_tracked_fraction: float
) -> MotionMeasure:
    ids = sorted(frames)
    first = grey(frames[ids[0]])
    h, w = first.shape
    diagonal = float(np.hypot(w, h))
    free = (~regions.exclusion(ids[0], (h, w))).astype(np.uint8) * 255
    min_distance = max(3, int(0.01 * diagonal))
    corners = cv2.goodFeaturesToTrack(first, _MAX_CORNERS, _CORNER_QUALITY, min_distance, mask=free)
    if corners is None or len(ids) < 2:
        return MotionMeasure(0.0 if len(ids) < 2 else float("inf"), {}, 0)
    picks = sorted({ids[int(round(i))] for i in np.linspace(1, len(ids) - 1, min(sample_frames, len(ids) - 1))})
    per_frame: dict[int, float] = {}
    for fid in picks:
        image = grey(frames[fid])
        moved, status, _ = cv2.calcOpticalFlowPyrLK(first, image, corners, None, winSize=_LK_WINDOW, maxLevel=_LK_LEVELS)
        ok = status.ravel() == 1
        if ok.sum() < min_tracked_fraction * len(corners):
            per_frame[fid] = float("inf")
            continue
        start, end = corners[ok, 0], moved[ok, 0]
        inside = (end[:, 0] >= 0) & (end[:, 0] < w) & (end[:, 1] >= 0) & (end[:, 1] < h)
        end_px = np.clip(end.round().astype(int), 0, [w - 1, h - 1])
        on_person = regions.exclusion(fid, (h, w))[end_px[:, 1], end_px[:, 0]]
        keep = inside & ~on_person
        if keep.sum() < min_tracked_fraction * len(corners):
            per_frame[fid] = float("inf")
            continue
        per_frame[fid] = float(np.median(np.linalg.norm(end[keep] - start[keep], axis=1)) / diagonal)
    return MotionMeasure(max(per_frame.values()), per_frame, len(corners))
