"""Self-calibration of the focal length from frame pairs (glimpse.sfm.focal) on synthetic fundamental
matrices of moving cameras, built from a known K, with and without pixel noise (the matrices then fitted by
OpenCV to the noisy points, as COLMAP would)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from glimpse.render.projection import fov_to_focal
from glimpse.sfm.focal import essential_cost, focal_from_fundamentals

WIDTH, HEIGHT = 320, 240
FOV_RANGE = (20.0, 120.0)


def intrinsics(focal: float) -> np.ndarray:
    return np.array([[focal, 0.0, WIDTH / 2], [0.0, focal, HEIGHT / 2], [0.0, 0.0, 1.0]])


def project(K: np.ndarray, R: np.ndarray, t: np.ndarray, points: np.ndarray) -> np.ndarray:
    cam = points @ R.T + t
    return (cam[:, :2] / cam[:, 2:]) * K[[0, 1], [0, 1]] + K[:2, 2]


def random_pairs(focal: float, count: int, seed: int, noise_px: float) -> np.ndarray:
    """[count, 3, 3] fundamental matrices fitted by OpenCV to the projections (with Gaussian pixel noise) of
    random points 3-8 m in front of the first of two cameras (a random turn and move between them)."""
    rng = np.random.default_rng(seed)
    K = intrinsics(focal)
    out = []
    while len(out) < count:
        points = np.column_stack([rng.uniform(-3, 3, 200), rng.uniform(-2, 2, 200), rng.uniform(3, 8, 200)])
        R = Rotation.from_rotvec(rng.normal(0, 0.08, 3)).as_matrix()
        t = rng.normal(0, 0.3, 3)
        a = project(K, np.eye(3), np.zeros(3), points) + rng.normal(0, noise_px, (200, 2))
        b = project(K, R, t, points) + rng.normal(0, noise_px, (200, 2))
        inside = np.all((np.hstack([a, b]) >= 0) & (np.hstack([a, b]) < [WIDTH, HEIGHT, WIDTH, HEIGHT]), axis=1)
        if inside.sum() < 30:
            continue
        matrix, _ = cv2.findFundamentalMat(a[inside], b[inside], cv2.FM_8POINT)
        if matrix is not None and matrix.shape == (3, 3):
            out.append(matrix)
    return np.array(out)


@pytest.mark.parametrize("fov_deg", [40.0, 70.0, 95.0])
def test_focal_from_exact_fundamental_matrices(fov_deg):
    focal = fov_to_focal(fov_deg, WIDTH)
    fundamentals = random_pairs(focal, 20, seed=int(fov_deg), noise_px=0.0)
    found = focal_from_fundamentals(fundamentals, np.array([WIDTH / 2, HEIGHT / 2]), WIDTH, FOV_RANGE)
    assert found == pytest.approx(focal, rel=1e-3)
    assert essential_cost(focal, fundamentals, np.array([WIDTH / 2, HEIGHT / 2])) < 1e-6


@pytest.mark.parametrize("fov_deg", [45.0, 80.0])
def test_focal_from_noisy_fundamental_matrices_is_within_two_percent(fov_deg):
    focal = fov_to_focal(fov_deg, WIDTH)
    centre = np.array([WIDTH / 2, HEIGHT / 2])
    fundamentals = random_pairs(focal, 40, seed=1, noise_px=0.5)
    found = focal_from_fundamentals(fundamentals, centre, WIDTH, FOV_RANGE)
    assert found == pytest.approx(focal, rel=0.02)
    # the default start (60 degrees) would be 20-40% off here
    assert abs(fov_to_focal(60.0, WIDTH) / focal - 1) > 0.2


def test_the_search_stays_in_its_range_and_needs_pairs():
    focal = fov_to_focal(70.0, WIDTH)
    fundamentals = random_pairs(focal, 10, seed=3, noise_px=0.0)
    narrow = focal_from_fundamentals(fundamentals, np.array([WIDTH / 2, HEIGHT / 2]), WIDTH, (20.0, 50.0))
    assert fov_to_focal(50.0, WIDTH) * 0.999 <= narrow <= fov_to_focal(20.0, WIDTH) * 1.001
    with pytest.raises(ValueError, match="at least one"):
        focal_from_fundamentals(np.zeros((0, 3, 3)), np.zeros(2), WIDTH, FOV_RANGE)
