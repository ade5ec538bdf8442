"""Keypoints smoothed along a track, offline: the whole video is known, so each keypoint is re-estimated from
its neighbours in time on both sides, without lag."""

from __future__ import annotations

import numpy as np


def smooth_keypoints(frames: np.ndarray, keypoints: np.ndarray, half_window: int) -> np.ndarray:
    """frames [T] increasing frame ids, keypoints [T, J, C] (C - 1 coordinates, then a confidence; 0 = missing:
    x, y, confidence for 2D keypoints) -> the same with
    every found keypoint replaced by a local linear fit (weighted least squares: confidence x a triangular
    kernel over frame ids within ``half_window``) evaluated at its frame. Missing keypoints stay missing, and a
    keypoint with no found neighbour keeps its value."""
    if half_window <= 0:
        return keypoints
    out = keypoints.copy()
    frames = np.asarray(frames, float)
    for t in range(len(frames)):
        near = np.abs(frames - frames[t]) <= half_window
        offsets = frames[near] - frames[t]
        kernel = 1.0 - np.abs(offsets) / (half_window + 1)
        for j in range(keypoints.shape[1]):
            if keypoints[t, j, -1] <= 0:
                continue
            weight = kernel * keypoints[near, j, -1]
            if np.count_nonzero(weight) < 2:
                continue
            design = np.stack([np.ones_like(offsets), offsets], 1) * np.sqrt(weight)[:, None]
            target = keypoints[near, j, :-1] * np.sqrt(weight)[:, None]
            solution, *_ = np.linalg.lstsq(design, target, rcond=None)
            out[t, j, :-1] = solution[0]
    return out
