"""Static-scene evidence from a static camera's frames: pixels whose colour hardly changes over
the whole video show the static scene (a wall, a table), never a moving person.

Inside a person's projected body, such a pixel is something static in front of the person (a
table before the legs), but only where the body itself moves: where the body surface seen at
that pixel changes over the video (SurfaceMotion). A person standing still looks static too,
so where its surface stays put a static colour tells nothing. Limits: a person who never moves
hides nothing we can find; lighting changes and camera noise above ``max_std`` hide static
pixels; a moving camera has no such evidence (stage 03 then uses the bodies alone).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np


def temporal_std(frames: Iterable[np.ndarray]) -> np.ndarray:
    """[H, W] the largest per-channel standard deviation over time of frames [H, W, 3] uint8
    (colours in [0, 1]); computed in one streaming pass (float64 sums)."""
    total = squares = None
    count = 0
    for frame in frames:
        values = frame.astype(np.float64) / 255.0
        if total is None:
            total, squares = np.zeros_like(values), np.zeros_like(values)
        total += values
        squares += values * values
        count += 1
    if count == 0:
        raise ValueError("temporal_std needs at least one frame")
    mean = total / count
    return np.sqrt(np.maximum(squares / count - mean * mean, 0.0)).max(-1)


class SurfaceMotion:
    """Per person and pixel, how much the body surface seen there changes over the video: the
    standard deviation (metres) of the canonical (rest-pose) position of the triangle covering it,
    over the frames where the person's projected body covers the pixel."""

    def __init__(self, people: list[str], height: int, width: int, face_points: np.ndarray):
        self.face_points = np.asarray(face_points, np.float64)  # [F, 3] rest-pose triangle centres
        shape = (height, width)
        self.count = {pid: np.zeros(shape) for pid in people}
        self.total = {pid: np.zeros((*shape, 3)) for pid in people}
        self.squares = {pid: np.zeros((*shape, 3)) for pid in people}

    def add(self, pid: str, faces: np.ndarray) -> None:
        """faces [H, W] the person's triangle at each pixel of one frame (-1: not covered)."""
        covered = faces >= 0
        points = self.face_points[faces[covered]]
        self.count[pid][covered] += 1
        self.total[pid][covered] += points
        self.squares[pid][covered] += points * points

    def moving(self, pid: str, min_std_m: float) -> np.ndarray:
        """[H, W] bool: covered in at least two frames by surface that moves by at least min_std_m."""
        count = np.maximum(self.count[pid], 1)[..., None]
        mean = self.total[pid] / count
        variance = np.maximum(self.squares[pid] / count - mean * mean, 0.0).sum(-1)
        return (self.count[pid] >= 2) & (np.sqrt(variance) >= min_std_m)
