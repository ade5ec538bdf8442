"""Real spherical harmonics (degrees 0-3) in the convention of 3D Gaussian Splatting.

The basis, its ordering and its signs are those of INRIA's ``utils/sh_utils.py``
(``eval_sh``) and gsplat's ``spherical_harmonics``: coefficient ``k = l*l + l + m``
holds ``Y_l^m`` for ``m = -l..l``, multiplied by ``(-1)^m`` relative to the textbook
real SH (so the degree-1 terms are ``-C1*y, C1*z, -C1*x``). The basis is orthonormal
over the unit sphere: ``integral Y_i Y_j dOmega = delta_ij``.

Colour from SH follows the 3DGS convention: ``rgb = max(sum_k Y_k(d) c_k + 0.5, 0)``,
so a Gaussian with only a DC coefficient ``c_0`` has colour ``C0 * c_0 + 0.5`` from
every direction.

Directions are *view directions* (from the camera centre to the Gaussian, as in
3DGS); they need not be unit length, they are normalised here.
"""

from __future__ import annotations

from typing import TypeVar

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

MAX_SH_DEGREE = 3

# Constants of the 3DGS SH basis (INRIA utils/sh_utils.py, gsplat spherical_harmonics).
C0 = 0.28209479177387814  # 1 / (2 sqrt(pi))
C1 = 0.4886025119029199  # sqrt(3 / (4 pi))
C2 = (
    1.0925484305920792,
    -1.0925484305920792,
    0.31539156525252005,
    -1.0925484305920792,
    0.5462742152960396,
)
C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)

# 3DGS stores colour as an offset from mid-grey: rgb = SH(d) + 0.5, clamped at 0.
RGB_OFFSET = 0.5
MIN_RGB = 0.0
SPATIAL_DIMS = 3

ArrayT = TypeVar("ArrayT", Tensor, np.ndarray, float)


def num_sh_coeffs(degree: int) -> int:
    """Number of SH coefficients per channel up to ``degree``: ``(degree + 1)^2``."""
    _check_degree(degree)
    return (degree + 1) ** 2


def sh_degree_from_num_coeffs(num_coeffs: int) -> int:
    """Inverse of :func:`num_sh_coeffs`; ValueError unless ``num_coeffs`` is 1, 4, 9 or 16."""
    for degree in range(MAX_SH_DEGREE + 1):
        if (degree + 1) ** 2 == num_coeffs:
            return degree
    valid = [(d + 1) ** 2 for d in range(MAX_SH_DEGREE + 1)]
    raise ValueError(
        f"{num_coeffs} SH coefficients per channel is no SH degree 0-{MAX_SH_DEGREE} (expected one of {valid})"
    )


def _check_degree(degree: int) -> None:
    if isinstance(degree, bool) or not isinstance(degree, int) or not 0 <= degree <= MAX_SH_DEGREE:
        raise ValueError(f"SH degree must be an integer in 0..{MAX_SH_DEGREE}, got {degree!r}")


def _check_dirs(dirs: Tensor) -> None:
    if dirs.ndim < 1 or dirs.shape[-1] != SPATIAL_DIMS:
        raise ValueError(f"dirs must have shape [..., 3], got {tuple(dirs.shape)}")


def sh_basis(degree: int, dirs: Tensor) -> Tensor:
    """The 3DGS real SH basis evaluated at view directions.

    Args:
        degree: SH degree, 0..3.
        dirs: ``[..., 3]`` directions of any length > 0 (normalised here; a zero
            vector gives the DC term only, and zeros for the others).

    Returns:
        ``[..., (degree+1)^2]`` basis values, same dtype and device as ``dirs``;
        differentiable with respect to ``dirs``.
    """
    _check_degree(degree)
    _check_dirs(dirs)
    d = F.normalize(dirs, dim=-1)  # [..., 3]
    x, y, z = d.unbind(-1)  # each [...]
    terms = [torch.full_like(x, C0)]
    if degree >= 1:
        terms += [-C1 * y, C1 * z, -C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        terms += [
            C2[0] * x * y,
            C2[1] * y * z,
            C2[2] * (2.0 * zz - xx - yy),
            C2[3] * x * z,
            C2[4] * (xx - yy),
        ]
    if degree >= 3:
        terms += [
            C3[0] * y * (3.0 * xx - yy),
            C3[1] * x * y * z,
            C3[2] * y * (4.0 * zz - xx - yy),
            C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            C3[4] * x * (4.0 * zz - xx - yy),
            C3[5] * z * (xx - yy),
            C3[6] * x * (xx - 3.0 * yy),
        ]
    return torch.stack(terms, dim=-1)  # [..., K]


class _ShCPU(torch.autograd.Function):
    """sh_to_rgb_torch for [N, K, C] coefficients and [N, 3] directions by the C++ kernel
    (csrc/preprocess_cpu.cpp), hand-written backward."""

    @staticmethod
    def forward(ctx, degree: int, sh_coeffs: Tensor, dirs: Tensor) -> Tensor:
        from glimpse.render.composite_cpu import extension

        inputs = [t.detach().contiguous() for t in (sh_coeffs, dirs)]
        ctx.save_for_backward(*inputs)
        ctx.degree = degree
        return extension().sh_forward(degree, *inputs)

    @staticmethod
    def backward(ctx, v_rgb: Tensor):
        from glimpse.render.composite_cpu import extension

        v_coeffs, v_dirs = extension().sh_backward(ctx.degree, *ctx.saved_tensors, v_rgb.float())
        return None, v_coeffs, v_dirs


def sh_to_rgb(degree: int, sh_coeffs: Tensor, dirs: Tensor) -> Tensor:
    """:func:`sh_to_rgb_torch`, computed by the C++ kernel for float32 CPU tensors of shapes [N, K, C] and
    [N, 3] where it builds, by gsplat's for float32 CUDA tensors of shapes [N, K, 3] and [N, 3] where it is
    installed (same maths, one pass instead of an autograd graph of elementwise kernels)."""
    from glimpse.render.composite_cpu import kernel_applies
    from glimpse.render.gsplat_backend import SH_CHANNELS, gsplat_ops_apply, sh_to_rgb_gsplat

    num_coeffs = num_sh_coeffs(degree)
    if (sh_coeffs.ndim == 3 and dirs.ndim == 2 and dirs.shape == (sh_coeffs.shape[0], SPATIAL_DIMS)
            and sh_coeffs.shape[1] >= num_coeffs):
        if kernel_applies(sh_coeffs, dirs):
            return _ShCPU.apply(degree, sh_coeffs, dirs)
        if sh_coeffs.shape[2] == SH_CHANNELS and gsplat_ops_apply(sh_coeffs, dirs):
            return sh_to_rgb_gsplat(degree, sh_coeffs, dirs)
    return sh_to_rgb_torch(degree, sh_coeffs, dirs)


def sh_to_rgb_torch(degree: int, sh_coeffs: Tensor, dirs: Tensor) -> Tensor:
    """Colour seen along ``dirs`` from SH coefficients (3DGS convention; the reference, in PyTorch).

    ``rgb = max(sum_k Y_k(dirs) * sh_coeffs[..., k, :] + 0.5, 0)``, summed over the
    first ``(degree+1)^2`` coefficients only (a degree-3 model can be shown at a lower
    active degree, as during 3DGS training).

    Args:
        degree: SH degree used, 0..3.
        sh_coeffs: ``[..., K, C]`` coefficients, ``K >= (degree+1)^2``, C channels
            (3 for RGB); ``[..., 0, :]`` is the DC term.
        dirs: ``[..., 3]`` view directions, any length > 0; batch dimensions
            broadcast against those of ``sh_coeffs``.

    Returns:
        ``[..., C]`` colours, >= 0 (not clamped above); differentiable.
    """
    num_coeffs = num_sh_coeffs(degree)
    if sh_coeffs.ndim < 2:
        raise ValueError(f"sh_coeffs must have shape [..., K, C], got {tuple(sh_coeffs.shape)}")
    if sh_coeffs.shape[-2] < num_coeffs:
        raise ValueError(
            f"SH degree {degree} needs {num_coeffs} coefficients per channel, "
            f"sh_coeffs has only {sh_coeffs.shape[-2]} (shape {tuple(sh_coeffs.shape)})"
        )
    basis = sh_basis(degree, dirs)  # [..., K']
    coeffs = sh_coeffs[..., :num_coeffs, :]  # [..., K', C]
    colour = (basis.unsqueeze(-1) * coeffs).sum(dim=-2)  # [..., C]
    return torch.clamp_min(colour + RGB_OFFSET, MIN_RGB)


def rgb_to_sh_dc(rgb: ArrayT) -> ArrayT:
    """DC SH coefficient whose colour is ``rgb`` from every direction: ``(rgb - 0.5) / C0``.

    Works on tensors, numpy arrays and floats, any shape.
    """
    return (rgb - RGB_OFFSET) / C0


def sh_dc_to_rgb(sh_dc: ArrayT) -> ArrayT:
    """Inverse of :func:`rgb_to_sh_dc`: ``sh_dc * C0 + 0.5`` (no clamping)."""
    return sh_dc * C0 + RGB_OFFSET


def rotate_view_dirs(dirs: Tensor, rotations: Tensor) -> Tensor:
    """Apply ``R^T`` to each direction: ``out[n] = rotations[n]^T @ dirs[n]``.

    With ``rotations[n]`` the rotation from a Gaussian's canonical frame to the world
    (``d_world = R d_canonical``), this brings world view directions into that
    canonical frame, ``d_canonical = R^T d_world``, where SH coefficients learnt in the
    canonical frame (e.g. of a posed person) must be evaluated. Rotations are assumed
    orthonormal (``R^T = R^-1``); lengths are kept.

    Args:
        dirs: ``[N, 3]`` directions in the world frame (more leading dims broadcast).
        rotations: ``[N, 3, 3]`` canonical-to-world rotation matrices.

    Returns:
        ``[N, 3]`` directions in each canonical frame; differentiable in both inputs.
    """
    _check_dirs(dirs)
    if rotations.ndim < 2 or rotations.shape[-2:] != (SPATIAL_DIMS, SPATIAL_DIMS):
        raise ValueError(f"rotations must have shape [N, 3, 3], got {tuple(rotations.shape)}")
    # (R^T d)_i = sum_j R_ji d_j
    return torch.einsum("...ji,...j->...i", rotations, dirs)
