"""Is the camera moving? Measured from the frames, outside the people.

Corners of the first frame (people excluded) are tracked into later frames with pyramidal Lucas-Kanade; the
camera's motion is the largest, over those frames, of the median displacement of the tracked corners, as a
fraction of the image diagonal. Losing most corners also counts as large motion. Stage 01 measures it on a
scene's frames, the ingest on a video's.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import cv2
import numpy as np

_MAX_CORNERS = 800
_CORNER_QUALITY = 0.01
_CORNER_SPACING = 0.01  # fraction of the image diagonal between two corners
_LK_WINDOW = (21, 21)
_LK_LEVELS = 4


@dataclass(frozen=True)
class MotionMeasure:
    """motion: largest median displacement / image diagonal; per_frame: frame id -> that ratio."""

    motion: float
    per_frame: dict[int, float]
    corners: int


def sample_ids(ids: list[int], count: int) -> list[int]:
    """Up to ``count`` ids spread evenly over ``ids[1:]`` (the frames compared with the first)."""
    if len(ids) < 2:
        return []
    return sorted({ids[round(i)] for i in np.linspace(1, len(ids) - 1, min(count, len(ids) - 1))})


def measure_motion(first: np.ndarray, later: Iterable[tuple[int, np.ndarray]], min_tracked_fraction: float,
                   excluded: Callable[[int | None], np.ndarray | None] = lambda fid: None) -> MotionMeasure:
    """first: [H, W] uint8 grey; later: (frame id, grey) pairs; excluded(frame id, or None for the first frame):
    [H, W] bool pixels to ignore (people), or None."""
    h, w = first.shape
    diagonal = float(np.hypot(w, h))
    mask = excluded(None)
    free = None if mask is None else (~mask).astype(np.uint8) * 255
    corners = cv2.goodFeaturesToTrack(first, _MAX_CORNERS, _CORNER_QUALITY,
                                      max(3, int(_CORNER_SPACING * diagonal)), mask=free)
    later = list(later)
    if not later:
        return MotionMeasure(0.0, {}, 0 if corners is None else len(corners))
    if corners is None:
        return MotionMeasure(float("inf"), {}, 0)
    per_frame: dict[int, float] = {}
    for fid, image in later:
        moved, status, _ = cv2.calcOpticalFlowPyrLK(first, image, corners, None, winSize=_LK_WINDOW, maxLevel=_LK_LEVELS)
        ok = status.ravel() == 1
        start, end = corners[ok, 0], moved[ok, 0]
        keep = (end[:, 0] >= 0) & (end[:, 0] < w) & (end[:, 1] >= 0) & (end[:, 1] < h)
        person = excluded(fid)
        if person is not None:
            end_px = np.clip(end.round().astype(int), 0, [w - 1, h - 1])
            keep &= ~person[end_px[:, 1], end_px[:, 0]]
        if keep.sum() < min_tracked_fraction * len(corners):
            per_frame[fid] = float("inf")
            continue
        per_frame[fid] = float(np.median(np.linalg.norm(end[keep] - start[keep], axis=1)) / diagonal)
    return MotionMeasure(max(per_frame.values()), per_frame, len(corners))
