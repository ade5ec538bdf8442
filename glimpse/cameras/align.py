"""Similarity alignment of camera trajectories (Umeyama 1991), and the rotation that aligns one direction with
another."""

from __future__ import annotations

from dataclasses import dataclass, replace

import math

import numpy as np
from scipy.spatial.transform import Rotation

from glimpse.cameras.model import PinholeCamera


@dataclass(frozen=True)
class Similarity:
    """x_target = scale * rotation @ x_source + translation."""

    scale: float
    rotation: np.ndarray  # (3, 3)
    translation: np.ndarray  # (3,)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """points: (N, 3) in the source frame -> (N, 3) in the target frame."""
        return self.scale * points @ self.rotation.T + self.translation

    def apply_to_camera(self, camera: PinholeCamera) -> PinholeCamera:
        """Re-express a source-frame camera in the target frame (target units).

        With x_s = R_a^T (x_t - t_a) / s, the camera x_c = R x_s + t becomes, in
        target units, s * x_c = (R R_a^T) x_t + (s t - R R_a^T t_a).
        """
        R = camera.R @ self.rotation.T
        t = self.scale * camera.t - R @ self.translation
        return replace(camera, R=R, t=t)


def umeyama(source: np.ndarray, target: np.ndarray) -> Similarity:
    """Least-squares similarity mapping source (N, 3) onto target (N, 3), N >= 3."""
    source, target = np.asarray(source, float), np.asarray(target, float)
    if source.shape != target.shape or source.ndim != 2 or source.shape[1] != 3 or len(source) < 3:
        raise ValueError(f"umeyama needs two (N>=3, 3) arrays of equal shape, found {source.shape}, {target.shape}")
    mu_s, mu_t = source.mean(0), target.mean(0)
    xs, xt = source - mu_s, target - mu_t
    var_s = (xs**2).sum() / len(source)
    if var_s <= 0:
        raise ValueError("umeyama: the source points are all identical (no baseline to align)")
    cov = xt.T @ xs / len(source)
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1
    rotation = U @ S @ Vt
    scale = float(np.trace(np.diag(D) @ S) / var_s)
    translation = mu_t - scale * rotation @ mu_s
    return Similarity(scale, rotation, translation)


def align_cameras(source: dict[int, PinholeCamera], target: dict[int, PinholeCamera]) -> Similarity:
    """Similarity taking ``source`` cameras (e.g. SfM's frame) onto ``target`` cameras of the same frames.

    Camera centres alone leave the rotation about their line undetermined when the path is
    straight (a dolly), so each camera also contributes two points along its viewing and
    down axes, at a distance equal to the spread of the centres (scaled into the source's
    units by a first, centre-only estimate of the scale).
    """
    common = sorted(set(source) & set(target))
    src_c = np.array([source[f].centre for f in common])
    dst_c = np.array([target[f].centre for f in common])
    scale = umeyama(src_c, dst_c).scale
    reach = max(float(np.linalg.norm(dst_c - dst_c.mean(0), axis=1).max()), 1e-6)

    def augmented(cameras: dict[int, PinholeCamera], centres: np.ndarray, length: float) -> np.ndarray:
        axes = [np.array([cameras[f].R[2] for f in common]), np.array([cameras[f].R[1] for f in common])]
        return np.concatenate([centres] + [centres + length * a for a in axes])

    return umeyama(augmented(source, src_c, reach / scale), augmented(target, dst_c, reach))


def rotation_between(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """[3, 3] the smallest rotation taking unit vector ``source`` to unit vector ``target`` (a half turn about an
    axis perpendicular to both when they are opposite)."""
    source, target = source / np.linalg.norm(source), target / np.linalg.norm(target)
    axis = np.cross(source, target)
    if np.linalg.norm(axis) < 1e-9:
        if np.dot(source, target) > 0:
            return np.eye(3)
        helper = np.eye(3)[np.argmin(np.abs(source))]
        axis = np.cross(source, helper)
        return Rotation.from_rotvec(math.pi * axis / np.linalg.norm(axis)).as_matrix()
    angle = math.atan2(np.linalg.norm(axis), np.dot(source, target))
    return Rotation.from_rotvec(angle * axis / np.linalg.norm(axis)).as_matrix()
