"""Spreading a few samples evenly over many points (farthest-point sampling): where 2D fits start their pose
hypotheses (glimpse.fit.priors.representative_poses) and the body's surface points of the silhouette term
(glimpse.fit.silhouette)."""

from __future__ import annotations

import numpy as np


def farthest_point_samples(points: np.ndarray, count: int, distance: np.ndarray | None = None) -> np.ndarray:
    """[count] indices into points [N, D], each next the point farthest (Euclidean) from those already taken;
    deterministic, count capped at N. ``distance`` [N]: each point's distance to what is taken already (the
    first sample is then the farthest from it); None: the first sample is index 0."""
    count = min(count, len(points))
    chosen = np.zeros(count, np.int64)
    if count == 0:
        return chosen
    if distance is not None:
        chosen[0] = int(distance.argmax())
    nearest = np.full(len(points), np.inf) if distance is None else distance
    for i in range(1, count):
        nearest = np.minimum(nearest, np.linalg.norm(points - points[chosen[i - 1]], axis=1))
        chosen[i] = int(nearest.argmax())
    return chosen
