"""Frames where the landmark model squeezed a person cut by the image's border into what shows.

A person entering or leaving across the frame's edge shows only part of their body. Given that part, BlazePose's
landmark model often still returns a whole skeleton, shrunk into the visible pixels at full confidence (on the
`demo` video, the head of a person entering from the right, still outside the frame, was put at their shoulders with
confidence 0.8). Such a frame's skeleton is much smaller than the same person's a few frames later, when more of
them shows: a walker's 2D torso (shoulder midpoint to hip midpoint) changes by a few percent over half a second.
Those frames' keypoints are not written (confidence 0, the ingest's "not seen"); the person's mask stays.
"""

from __future__ import annotations

import numpy as np

from glimpse.ingest.sides import torso_lengths


def squeezed_at_border(times_s: np.ndarray, keypoints: np.ndarray, boxes: np.ndarray, image_size: tuple[int, int],
                       border_fraction: float, window_s: float, max_shrink: float) -> np.ndarray:
    """[T] bool: the frames of one track whose skeleton was squeezed into a part of the person cut by the border.

    times_s [T] (seconds), keypoints [T, 17, 3] pixels and confidence, boxes [T, 4] the landmarks' boxes (x0, y0,
    x1, y1) in the same pixels, image_size (width, height). A frame is squeezed when its box comes within
    ``border_fraction`` of the image's height of an edge and its torso is shorter than (1 - ``max_shrink``) times
    the median torso of the track's other frames within ``window_s`` seconds (frames with no such neighbour are
    kept)."""
    width, height = image_size
    margin = border_fraction * height
    at_border = ((boxes[:, 0] <= margin) | (boxes[:, 1] <= margin) | (boxes[:, 2] >= width - 1 - margin)
                 | (boxes[:, 3] >= height - 1 - margin))
    torso = torso_lengths(keypoints)
    squeezed = np.zeros(len(times_s), bool)
    for k in np.flatnonzero(at_border & np.isfinite(torso)):
        near = (np.abs(times_s - times_s[k]) <= window_s) & np.isfinite(torso)
        near[k] = False
        if near.any():
            squeezed[k] = torso[k] < (1.0 - max_shrink) * np.median(torso[near])
    return squeezed
