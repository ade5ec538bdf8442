"""Joints that another person hides.

BlazePose's landmark model returns every landmark of the person in its crop, hidden or not, and its visibility
score speaks mostly of self-occlusion: where a nearer person walks in front, the hidden person's landmarks are
still given, guessed from the rest of the body, at high visibility (the `demo` video of seed 2: the far walker's
keypoints 3.7-4.1 px off on average at 128 px while behind the near walker, about 1 px elsewhere). The
ingest's depth-ordered labels say who is in front at each pixel, so a joint that lands on the pixels of someone
nearer is hidden behind them; it is written as not seen (confidence 0), as the scene format asks of hidden joints.
Someone farther cannot hide a joint: where the labels give them a pixel under the person's joint, the joint is off
the person's body or the labels took a pixel of it (`crowd` seed 4, frame 55: the mask of the person behind took
3,789 of the nearer one's 9,991 visible pixels, their shoulder, hip and knee among them), and it is kept.
"""

from __future__ import annotations

from collections.abc import Callable, Collection

import numpy as np

NOBODY = 0  # the labels' value where no person is


def joints_on_others(points: np.ndarray, labels: np.ndarray, own_label: int, farther: Collection[int] = ()
                     ) -> np.ndarray:
    """[K] bool: which of ``points`` [K, 2] (pixels of ``labels``, pixel centres at integers) lie on a pixel
    that ``labels`` [H, W] gives to a person other than ``own_label`` and not one of ``farther`` (labels of
    people behind this one; points outside the image: False)."""
    height, width = labels.shape
    column, row = np.round(points[:, 0]).astype(int), np.round(points[:, 1]).astype(int)
    inside = (column >= 0) & (column < width) & (row >= 0) & (row < height)
    owner = np.full(len(points), NOBODY, labels.dtype)
    owner[inside] = labels[row[inside], column[inside]]
    return (owner != NOBODY) & (owner != own_label) & ~np.isin(owner, list(farther))


def lowest_rows(labels: np.ndarray) -> dict[int, float]:
    """Label -> the lowest row (pixels) holding one of its pixels, for every person in ``labels`` [H, W]."""
    return {int(label): float(np.nonzero((labels == label).any(1))[0][-1])
            for label in np.unique(labels) if label != NOBODY}


def feet_rows(bottoms: dict[int, float], frame_id: int, window: int) -> float | None:
    """The median of a person's lowest mask rows (frame id -> row) over ``window`` frames either side of
    ``frame_id``, None when none is known: who stands nearer on one floor (their feet lower in the image), as the
    depth-ordered masks rank people, over a window (a hidden person's mask can reach down over the front person's
    legs for a few frames)."""
    rows = [bottoms[frame] for frame in range(frame_id - window, frame_id + window + 1) if frame in bottoms]
    return float(np.median(rows)) if rows else None


def hidden_joints(tracks: list[tuple[int, list[int], np.ndarray]], labels_of: Callable[[int], np.ndarray],
                  window: int) -> list[np.ndarray]:
    """Per track (its label, frame ids [T], keypoints [T, K, >= 2] in pixels of the labels), [T, K] bool: the
    joints on the pixels of someone nearer (:func:`joints_on_others`; nearer: feet lower, :func:`feet_rows` over
    ``window``, among the tracks given; a label not among them hides). ``labels_of(frame id)``: the frame's
    depth-ordered labels, read twice per frame (the feet of the frames after are needed first)."""
    frames = sorted({frame_id for _, frame_ids, _ in tracks for frame_id in frame_ids})
    bottoms: dict[int, dict[int, float]] = {label: {} for label, _, _ in tracks}
    for frame_id in frames:
        for label, row in lowest_rows(labels_of(frame_id)).items():
            if label in bottoms:
                bottoms[label][frame_id] = row
    row_of = [{frame_id: k for k, frame_id in enumerate(frame_ids)} for _, frame_ids, _ in tracks]
    hidden = [np.zeros(points.shape[:2], bool) for _, _, points in tracks]
    for frame_id in frames:
        labels = labels_of(frame_id)
        feet = {label: feet_rows(rows, frame_id, window) for label, rows in bottoms.items()}
        for k, (label, _, points) in enumerate(tracks):
            if frame_id not in row_of[k]:
                continue
            mine = feet[label]
            farther = [other for other, theirs in feet.items()
                       if other != label and mine is not None and theirs is not None and theirs < mine]
            hidden[k][row_of[k][frame_id]] = joints_on_others(points[row_of[k][frame_id], :, :2], labels, label,
                                                              farther)
    return hidden
