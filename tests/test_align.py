"""Similarity alignment of camera sets (stage 01's forced-SfM alignment)."""

import numpy as np
from scipy.spatial.transform import Rotation

from glimpse.cameras.align import Similarity, align_cameras, umeyama
from glimpse.cameras.model import PinholeCamera


def test_umeyama_recovers_a_similarity():
    rng = np.random.default_rng(0)
    points = rng.normal(size=(20, 3))
    truth = Similarity(2.5, Rotation.random(random_state=1).as_matrix(), np.array([1.0, -2.0, 0.5]))
    found = umeyama(points, truth.apply(points))
    assert np.isclose(found.scale, 2.5) and np.allclose(found.rotation, truth.rotation)
    assert np.allclose(found.translation, truth.translation)


def test_cameras_on_a_straight_dolly_are_aligned_in_rotation_too():
    """Centres on a line fix scale and position but not the rotation about the line."""
    K = np.eye(3)
    target = {}
    for i in range(10):
        R = Rotation.from_euler("y", 0.05 * i).as_matrix()
        centre = np.array([0.3 * i, 1.5, -2.0])  # a straight dolly
        target[i] = PinholeCamera(K, R, -R @ centre, 2, 2)
    to_sfm = Similarity(0.25, Rotation.random(random_state=3).as_matrix(), np.array([0.4, 0.1, -0.7]))
    source = {i: to_sfm.apply_to_camera(cam) for i, cam in target.items()}  # in "SfM units"
    back = align_cameras(source, target)
    for i, cam in source.items():
        aligned = back.apply_to_camera(cam)
        assert np.allclose(aligned.R, target[i].R, atol=1e-9) and np.allclose(aligned.centre, target[i].centre)
