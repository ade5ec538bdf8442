"""Tracks that are patterns, not people: a torso upside down for most of the video.

On a moving camera no background plate rules out texture, and BlazePose's landmark model, given a region of a busy
wall, sometimes returns a whole skeleton at high confidence (the `moving_camera` fixture, seed 0: an 11-frame track
on its patterned wall, 120 px tall, above the size rule). Such a skeleton has no reason to stand upright, and that
one stood on its head in every frame whose torso it gave; over every real person of the fixtures' ingests no frame
did. A person in a handstand for most of their frames is the price (``ingest.track_max_upside_down`` 1 keeps every
track).
"""

from __future__ import annotations

import numpy as np

from glimpse.ingest.sides import torso_axes

UPSIDE_DOWN_COS = -0.5  # a torso (mid hip -> mid shoulder) more than 120 degrees from the image's up is upside down


def upside_down_share(keypoints: np.ndarray) -> float:
    """Share of a track's frames showing its torso (both shoulders and both hips, confidence > 0) in which the torso
    points down the image; keypoints [T, 17, 3] COCO-17 pixels (y down) and confidence. 0 when no frame shows it."""
    torso = torso_axes(keypoints)
    torso = torso[~np.isnan(torso[:, 0])]
    if not len(torso):
        return 0.0
    cos_from_up = -torso[:, 1] / np.maximum(np.linalg.norm(torso, axis=1), 1e-9)
    return float((cos_from_up < UPSIDE_DOWN_COS).mean())
