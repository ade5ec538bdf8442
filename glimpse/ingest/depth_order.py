"""Which person owns each pixel where several people's segmentations overlap: people ranked by how near they are.

The landmark model segments every person in its crop, so where people overlap several segmentations claim the same
pixels; the nearest person whose skeleton passes through a pixel keeps it (their body hides whoever is behind).
"""

from __future__ import annotations

import numpy as np

from glimpse.ingest.observation import Observation, Track, observed_skeleton_distance


def nearness_rank(track: Track, observation: Observation, cue: str, frames: int) -> float:
    """Sort key, smaller = nearer the camera. ``feet``: the lowest landmark's image row, higher up = farther
    (people on one floor seen from above it; right for a child and an adult alike), the median over the
    track's last ``frames`` frames (:meth:`Tracker.step` records the current one): a person hidden behind
    someone has their feet guessed onto the front person's for a few frames. ``bones``: the depth proxy,
    metres per pixel along the bones (the landmark model's metric lengths are an adult's whatever the person's
    size, so a child is ranked too far)."""
    if cue != "feet":
        return observation.depth
    recent = [box[3] for frame, box in zip(track.frames, track.boxes) if frame > track.frames[-1] - frames]
    return -float(np.median(recent)) if recent else -float(observation.box[3])


def depth_ordered_labels(observations: list[tuple[Track, Observation]], shape: tuple[int, int],
                         threshold: float, body_radius: float, cue: str = "feet", cue_frames: int = 1) -> np.ndarray:
    """[H, W] uint16: 0 for nobody, else 1 + the index of the track that owns the pixel.

    A pixel claimed by one person's segmentation is theirs. Where several claim it (the landmark model segments
    every person in its crop), the nearest person (:func:`nearness_rank` by ``cue`` over ``cue_frames``) whose
    skeleton lies within ``body_radius`` torso lengths takes it (their body hides whoever is behind); otherwise
    the person whose skeleton is nearest."""
    labels = np.zeros(shape, np.uint16)
    if not observations:
        return labels
    ordered = sorted(observations, key=lambda pair: nearness_rank(*pair, cue, cue_frames))
    claims = np.stack([o.probability > threshold for _, o in ordered])
    count = claims.sum(0)
    ids = np.array([t.index + 1 for t, _ in ordered], np.uint16)
    labels[count == 1] = ids[np.argmax(claims[:, count == 1], axis=0)]
    contested = count > 1
    if contested.any():
        distance = np.stack([observed_skeleton_distance(o)[contested] for _, o in ordered])
        distance = np.where(claims[:, contested], distance, np.inf)
        on_body = distance < body_radius
        front = np.where(on_body.any(0), np.argmax(on_body, axis=0), np.argmin(distance, axis=0))
        labels[contested] = ids[front]
    return labels
