"""Joints that another person hides.

BlazePose's landmark model returns every landmark of the person in its crop, hidden or not, and its visibility
score speaks mostly of self-occlusion: where a nearer person walks in front, the hidden person's landmarks are
still given, guessed from the rest of the body, at high visibility (the `demo` video of seed 2: the far walker's
keypoints 3.7-4.1 px off on average at 128 px while behind the near walker, about 1 px elsewhere). The
ingest's depth-ordered labels say who is in front at each pixel, so a joint that lands on another person's pixels is hidden behind them; it is
written as not seen (confidence 0), as the scene format asks of hidden joints.
"""

from __future__ import annotations

import numpy as np

NOBODY = 0  # the labels' value where no person is


def joints_on_others(points: np.ndarray, labels: np.ndarray, own_label: int) -> np.ndarray:
    """[K] bool: which of ``points`` [K, 2] (pixels of ``labels``, pixel centres at integers) lie on a pixel
    that ``labels`` [H, W] gives to a person other than ``own_label`` (points outside the image: False)."""
    height, width = labels.shape
    column, row = np.round(points[:, 0]).astype(int), np.round(points[:, 1]).astype(int)
    inside = (column >= 0) & (column < width) & (row >= 0) & (row < height)
    owner = np.full(len(points), NOBODY, labels.dtype)
    owner[inside] = labels[row[inside], column[inside]]
    return (owner != NOBODY) & (owner != own_label)
