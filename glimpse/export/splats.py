"""Standard 3DGS Gaussians of a posed person and of a whole frame (CONTRACTS.md "Exporting a posed
person as standard 3DGS").

A person's canonical Gaussian moves into a frame by its blended skinning transform A (3x3 part):
its covariance becomes ``A Σ Aᵀ`` (exact), stored again as scales and a rotation (its
eigen-decomposition); its spherical harmonics, learnt in the canonical frame, are rotated by the
polar (closest-rotation) part R of A, the rotation the renderer applies to view directions
(``rotate_view_dirs``), so the exported Gaussian shows the colour the run rendered from every
direction. Each SH band l rotates by a (2l+1)x(2l+1) matrix, found here by least squares on a fixed
set of directions (exact: a band is closed under rotation).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
from scipy.spatial.transform import Rotation
from torch import Tensor

from glimpse.gaussians.model import GaussianModel
from glimpse.gaussians.ply import GaussianSplats
from glimpse.body.skinning import deform_gaussians
from glimpse.humans.person import PersonGaussians, polar_rotation
from glimpse.render.projection import quat_scale_to_covariance
from glimpse.render.sh import num_sh_coeffs, sh_basis

SAMPLE_DIRECTIONS = 64  # directions the band rotations are fitted on (degree 3 needs 16 at least)
MIN_VARIANCE = 1e-20  # squared metres: floor of a covariance eigenvalue before its square root
OPACITY_EPS = 1e-7  # opacities are clamped to [eps, 1 - eps] before the logit


def fibonacci_directions(count: int) -> Tensor:
    """[count, 3] unit vectors spread evenly over the sphere (float64)."""
    k = torch.arange(count, dtype=torch.float64) + 0.5
    z = 1.0 - 2.0 * k / count
    radius = torch.sqrt(1.0 - z * z)
    azimuth = math.pi * (3.0 - math.sqrt(5.0)) * k
    return torch.stack([radius * torch.cos(azimuth), radius * torch.sin(azimuth), z], dim=1)


def rotate_sh(sh: Tensor, rotations: Tensor) -> Tensor:
    """sh [N, K, C] coefficients evaluated at canonical directions (colour(d) = Σ sh_k Y_k(Rᵀ d) for a world
    direction d, rotations [N, 3, 3] canonical-to-world) -> [N, K, C] coefficients giving the same colour
    evaluated at world directions directly: colour(d) = Σ out_k Y_k(d)."""
    degree = round(math.sqrt(sh.shape[1])) - 1
    if degree == 0:
        return sh.clone()
    dirs = fibonacci_directions(SAMPLE_DIRECTIONS)  # [M, 3]
    basis = sh_basis(degree, dirs)  # [M, K]
    rotated = sh_basis(degree, torch.einsum("nji,mj->nmi", rotations.double(), dirs))  # Y(Rᵀ d_m): [N, M, K]
    out = sh.clone()
    for band in range(1, degree + 1):
        cols = slice(num_sh_coeffs(band - 1), num_sh_coeffs(band))
        # X with Y_band(d) X = Y_band(Rᵀ d) for every d: then colour = Y_band(d) (X sh_band)
        band_map = torch.linalg.pinv(basis[:, cols]) @ rotated[:, :, cols]  # [N, 2l+1, 2l+1]
        out[:, cols] = (band_map @ sh[:, cols].double()).to(sh.dtype)
    return out


def covariance_to_scales_quats(covariances: Tensor) -> tuple[Tensor, Tensor]:
    """covariances [N, 3, 3] symmetric -> (scales [N, 3], quats [N, 4] wxyz) with R diag(s²) Rᵀ = Σ."""
    variances, axes = torch.linalg.eigh(covariances.double())
    flip = torch.linalg.det(axes) < 0
    axes[flip, :, 0] = -axes[flip, :, 0]  # a proper rotation (det +1)
    xyzw = Rotation.from_matrix(axes.numpy()).as_quat()
    quats = torch.as_tensor(np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1), dtype=covariances.dtype)
    return variances.clamp(min=MIN_VARIANCE).sqrt().to(covariances.dtype), quats


def _splats(means: Tensor, covariances: Tensor, opacities: Tensor, sh: Tensor) -> GaussianSplats:
    scales, quats = covariance_to_scales_quats(covariances)
    p = opacities.clamp(OPACITY_EPS, 1.0 - OPACITY_EPS)
    return GaussianSplats.from_tensors(means, sh, torch.log(p / (1.0 - p)), torch.log(scales), quats)


@torch.no_grad()
def posed_person_splats(person: PersonGaussians, frame_id: int) -> GaussianSplats:
    """The person's Gaussians posed in ``frame_id`` (world frame) as standard 3DGS, all SH bands."""
    model = person.model
    blended = person.blended_transforms(frame_id)
    covariances = quat_scale_to_covariance(model.quats, model.scales())
    means, covariances = deform_gaussians(model.means, covariances, blended)
    sh = rotate_sh(model.sh(), polar_rotation(blended[:, :3, :3]))
    return _splats(means, covariances, model.opacities(), sh)


def with_sh_degree(splats: GaussianSplats, degree: int) -> GaussianSplats:
    """The same Gaussians with SH of ``degree``: higher bands padded with zeros (viewers that only read
    degree 3, like INRIA's SIBR) or dropped."""
    coeffs = num_sh_coeffs(degree)
    sh = splats.sh[:, :coeffs]
    sh = np.pad(sh, ((0, 0), (0, coeffs - sh.shape[1]), (0, 0)))
    return GaussianSplats(splats.means, sh, splats.opacity_logits, splats.log_scales, splats.quats)


def concatenate(parts: Sequence[GaussianSplats]) -> GaussianSplats:
    """One set of Gaussians from several; SH padded with zeros to the highest degree among them."""
    degree = max(part.sh_degree for part in parts)
    parts = [with_sh_degree(part, degree) for part in parts]
    return GaussianSplats(*(np.concatenate([getattr(part, name) for part in parts])
                            for name in ("means", "sh", "opacity_logits", "log_scales", "quats")))


def frame_splats(background: GaussianModel | None, people: Sequence[PersonGaussians], frame_id: int
                 ) -> GaussianSplats:
    """The whole scene at ``frame_id``: the background (when given) and every person present, posed."""
    parts = [background.to_splats()] if background is not None else []
    parts += [posed_person_splats(person, frame_id) for person in people if person.in_frame(frame_id)]
    if not parts:
        raise ValueError(f"frame {frame_id}: no background and nobody present, nothing to export")
    return concatenate(parts)


@torch.no_grad()
def rotated_splats(splats: GaussianSplats, rotation: np.ndarray) -> GaussianSplats:
    """The same Gaussians in a world turned by ``rotation`` [3, 3] (new point = rotation @ old point): means,
    orientations and SH (colours from every direction unchanged), scales and opacities as they are."""
    quats = Rotation.from_matrix(rotation) * Rotation.from_quat(splats.quats[:, [1, 2, 3, 0]])
    xyzw = quats.as_quat()
    sh = rotate_sh(torch.as_tensor(splats.sh), torch.as_tensor(rotation)[None])
    return GaussianSplats(splats.means @ rotation.T.astype(np.float32), sh.numpy(), splats.opacity_logits,
                          splats.log_scales, np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1))
