"""The focal length of a video's camera from the fundamental matrices of its frame pairs.

With square pixels and the principal point at the image centre, one unknown remains: the focal length
f. For the right f, every pair's essential matrix E = Kᵀ F K has two equal non-zero singular values
(Mendonça and Cipolla's self-calibration); for a wrong one they differ. The cost of a candidate f is the
median over pairs of the singular values' relative spread, minimised over a log-spaced range of fields of
view and refined by golden-section search. The median keeps pairs with a poor matrix from pulling the answer.
Pairs that COLMAP explains by a homography (the camera mostly turned, or a plane filled the view) carry no
usable F and are left out: K⁻¹ H K is a rotation only for a pure turn, and walls are planes, so a
homography-based estimate was measured 40% off on a dollying camera in a room.

Incremental SfM that estimates f while it grows from one pair can settle in a mirrored reconstruction with
f far off (a camera that mostly pans, with a starting value 45% off, did here); starting it from this f and
keeping f fixed until a last bundle adjustment does not (docs/cameras.md).
"""

from __future__ import annotations

import math

import numpy as np

from glimpse.render.projection import fov_to_focal

GRID_STEPS = 200  # log-spaced focal lengths tried before the golden-section refinement
GOLDEN_ITERATIONS = 40
GOLDEN = (math.sqrt(5) - 1) / 2


def _intrinsics(focal: float, principal_point: np.ndarray) -> np.ndarray:
    return np.array([[focal, 0.0, principal_point[0]], [0.0, focal, principal_point[1]], [0.0, 0.0, 1.0]])


def essential_cost(focal: float, fundamentals: np.ndarray, principal_point: np.ndarray) -> float:
    """Median over pairs of (σ1 - σ2) / (σ1 + σ2) of E = Kᵀ F K (0 for the true focal length); fundamentals
    [P, 3, 3] in pixels whose principal point is ``principal_point`` (2,)."""
    K = _intrinsics(focal, principal_point)
    s = np.linalg.svd(K.T[None] @ fundamentals @ K[None], compute_uv=False)  # [P, 3], descending
    return float(np.median((s[:, 0] - s[:, 1]) / np.maximum(s[:, 0] + s[:, 1], 1e-300)))


def focal_from_fundamentals(fundamentals: np.ndarray, principal_point: np.ndarray, side_px: int,
                            fov_range_deg: tuple[float, float]) -> float:
    """The focal length (pixels) minimising :func:`essential_cost` over ``fundamentals`` [P, 3, 3], P >= 1,
    searched between the fields of view ``fov_range_deg`` (degrees across ``side_px`` pixels): a log-spaced
    grid, then golden-section search."""
    if len(fundamentals) == 0:
        raise ValueError("focal_from_fundamentals needs at least one frame pair's fundamental matrix")

    def at(log_focal: float) -> float:
        return essential_cost(math.exp(log_focal), fundamentals, principal_point)

    wide, narrow = max(fov_range_deg), min(fov_range_deg)
    grid = np.log(np.geomspace(fov_to_focal(wide, side_px), fov_to_focal(narrow, side_px), GRID_STEPS))
    best = int(np.argmin([at(g) for g in grid]))
    lo, hi = grid[max(best - 1, 0)], grid[min(best + 1, len(grid) - 1)]
    a, b = hi - GOLDEN * (hi - lo), lo + GOLDEN * (hi - lo)
    cost_a, cost_b = at(a), at(b)
    for _ in range(GOLDEN_ITERATIONS):
        if cost_a < cost_b:
            hi, b, cost_b = b, a, cost_a
            a = hi - GOLDEN * (hi - lo)
            cost_a = at(a)
        else:
            lo, a, cost_a = a, b, cost_b
            b = lo + GOLDEN * (hi - lo)
            cost_b = at(b)
    return math.exp((lo + hi) / 2)
