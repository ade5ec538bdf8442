"""Tests of glimpse.render.sh against independent formulas, quadrature and finite differences."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from glimpse.render.sh import (
    C0,
    MAX_SH_DEGREE,
    num_sh_coeffs,
    rgb_to_sh_dc,
    rotate_view_dirs,
    sh_basis,
    sh_dc_to_rgb,
    sh_degree_from_num_coeffs,
    sh_to_rgb,
)

DEGREES = list(range(MAX_SH_DEGREE + 1))
F64 = torch.float64
# Gauss-Legendre in cos(theta) x uniform in phi is exact for polynomials of degree
# <= 2*GL_NODES-1 in z and < PHI_NODES in phi; products of two degree-3 harmonics have
# degree 6, so these sizes integrate them exactly up to rounding.
GL_NODES = 8
PHI_NODES = 16
ORTHONORMAL_TOL = 1e-12  # |integral Y_i Y_j - delta_ij|, float64, exact quadrature
# Plain Monte-Carlo on the sphere: the error of each entry is ~ sd / sqrt(n), sd <= ~3.
MC_SAMPLES = 400_000
MC_TOL = 0.03


def _generator(seed: int = 0) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def _random_dirs(n: int, seed: int = 0, dtype: torch.dtype = F64) -> torch.Tensor:
    """[n, 3] directions of random lengths in [0.3, 3) (not unit)."""
    g = _generator(seed)
    d = torch.randn(n, 3, generator=g, dtype=dtype)
    lengths = 0.3 + 2.7 * torch.rand(n, 1, generator=g, dtype=dtype)
    return d / d.norm(dim=-1, keepdim=True) * lengths


def _random_rotation(seed: int) -> torch.Tensor:
    """[3, 3] random proper rotation (QR of a Gaussian matrix, det fixed to +1)."""
    q, r = torch.linalg.qr(torch.randn(3, 3, generator=_generator(seed), dtype=F64))
    q = q * torch.sign(torch.diagonal(r))
    if torch.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def _textbook_real_sh(dirs: torch.Tensor) -> torch.Tensor:
    """[..., 16] textbook real SH Y_l^m (l = 0..3, m = -l..l) in Cartesian form.

    Written from the standard table (e.g. Wikipedia "Table of spherical harmonics",
    real harmonics), *without* the 3DGS signs; uses unit-sphere forms such as 3z^2-1.
    """
    d = dirs / dirs.norm(dim=-1, keepdim=True)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    pi = math.pi
    return torch.stack(
        [
            0.5 * math.sqrt(1 / pi) * torch.ones_like(x),
            math.sqrt(3 / (4 * pi)) * y,
            math.sqrt(3 / (4 * pi)) * z,
            math.sqrt(3 / (4 * pi)) * x,
            0.5 * math.sqrt(15 / pi) * x * y,
            0.5 * math.sqrt(15 / pi) * y * z,
            0.25 * math.sqrt(5 / pi) * (3 * z**2 - 1),
            0.5 * math.sqrt(15 / pi) * x * z,
            0.25 * math.sqrt(15 / pi) * (x**2 - y**2),
            0.25 * math.sqrt(35 / (2 * pi)) * y * (3 * x**2 - y**2),
            0.5 * math.sqrt(105 / pi) * x * y * z,
            0.25 * math.sqrt(21 / (2 * pi)) * y * (5 * z**2 - 1),
            0.25 * math.sqrt(7 / pi) * (5 * z**3 - 3 * z),
            0.25 * math.sqrt(21 / (2 * pi)) * x * (5 * z**2 - 1),
            0.25 * math.sqrt(105 / pi) * z * (x**2 - y**2),
            0.25 * math.sqrt(35 / (2 * pi)) * x * (x**2 - 3 * y**2),
        ],
        dim=-1,
    )


def _gsplat_signs() -> torch.Tensor:
    """[16] the 3DGS sign of each basis function relative to the textbook one: (-1)^m."""
    return torch.tensor([(-1.0) ** m for l in range(MAX_SH_DEGREE + 1) for m in range(-l, l + 1)], dtype=F64)


def _sphere_quadrature() -> tuple[torch.Tensor, torch.Tensor]:
    """Unit directions [Q, 3] and weights [Q] summing to 4 pi."""
    z_nodes, z_weights = np.polynomial.legendre.leggauss(GL_NODES)
    phi = 2 * np.pi * np.arange(PHI_NODES) / PHI_NODES
    z, ph = np.meshgrid(z_nodes, phi, indexing="ij")
    r = np.sqrt(1 - z**2)
    dirs = np.stack([r * np.cos(ph), r * np.sin(ph), z], axis=-1).reshape(-1, 3)
    weights = np.repeat(z_weights, PHI_NODES) * (2 * np.pi / PHI_NODES)
    return torch.from_numpy(dirs), torch.from_numpy(weights)


# --- basis values -----------------------------------------------------------------------


@pytest.mark.parametrize("degree", DEGREES)
def test_basis_matches_textbook_real_sh_with_3dgs_signs(degree: int) -> None:
    dirs = _random_dirs(500, seed=degree)
    k = num_sh_coeffs(degree)
    expected = _textbook_real_sh(dirs)[:, :k] * _gsplat_signs()[:k]
    got = sh_basis(degree, dirs)
    assert got.shape == (500, k) and got.dtype == F64
    torch.testing.assert_close(got, expected, rtol=1e-12, atol=1e-12)


def test_basis_degree1_examples() -> None:
    """The documented degree-1 terms: -C1*y, C1*z, -C1*x, on the axes."""
    c1 = math.sqrt(3 / (4 * math.pi))
    axes = torch.eye(3, dtype=F64) * 2.5  # x, y, z axes, not unit length
    expected = torch.tensor(
        [[C0, 0.0, 0.0, -c1], [C0, -c1, 0.0, 0.0], [C0, 0.0, c1, 0.0]], dtype=F64
    )
    torch.testing.assert_close(sh_basis(1, axes), expected, rtol=0, atol=1e-15)


def test_basis_lower_degree_is_prefix_and_batch_shapes() -> None:
    dirs = _random_dirs(24, seed=3).reshape(2, 3, 4, 3)
    full = sh_basis(MAX_SH_DEGREE, dirs)
    assert full.shape == (2, 3, 4, 16)
    for degree in DEGREES:
        torch.testing.assert_close(sh_basis(degree, dirs), full[..., : num_sh_coeffs(degree)], rtol=0, atol=0)


def test_basis_is_scale_invariant_and_float32() -> None:
    dirs = _random_dirs(50, seed=4)
    torch.testing.assert_close(sh_basis(3, dirs), sh_basis(3, 7.0 * dirs), rtol=1e-12, atol=1e-12)
    out32 = sh_basis(3, dirs.float())
    assert out32.dtype == torch.float32
    torch.testing.assert_close(out32, sh_basis(3, dirs).float(), rtol=1e-5, atol=1e-6)


def test_quadrature_is_orthonormal() -> None:
    """integral over S^2 of Y_i Y_j = delta_ij, to 1e-12 (quadrature exact for degree <= 6)."""
    dirs, weights = _sphere_quadrature()
    assert abs(weights.sum().item() - 4 * math.pi) < 1e-12
    basis = sh_basis(MAX_SH_DEGREE, dirs)  # [Q, 16]
    gram = basis.T @ (basis * weights[:, None])
    torch.testing.assert_close(gram, torch.eye(16, dtype=F64), rtol=0, atol=ORTHONORMAL_TOL)


def test_monte_carlo_is_orthonormal() -> None:
    """Same with uniform random directions: 4 pi * mean(Y_i Y_j) = delta_ij within 0.03."""
    dirs = torch.randn(MC_SAMPLES, 3, generator=_generator(5), dtype=F64)
    basis = sh_basis(MAX_SH_DEGREE, dirs)
    gram = 4 * math.pi * (basis.T @ basis) / MC_SAMPLES
    torch.testing.assert_close(gram, torch.eye(16, dtype=F64), rtol=0, atol=MC_TOL)


def test_bad_arguments_are_refused() -> None:
    dirs = _random_dirs(4)
    for degree in (-1, 4, 1.0, True):
        with pytest.raises(ValueError, match="SH degree"):
            sh_basis(degree, dirs)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"\[\.\.\., 3\]"):
        sh_basis(1, torch.zeros(4, 2, dtype=F64))
    assert [num_sh_coeffs(d) for d in DEGREES] == [1, 4, 9, 16]
    assert [sh_degree_from_num_coeffs(k) for k in (1, 4, 9, 16)] == DEGREES
    with pytest.raises(ValueError):
        sh_degree_from_num_coeffs(5)


# --- colour -----------------------------------------------------------------------------


@pytest.mark.parametrize("degree", DEGREES)
def test_dc_only_colour_is_view_independent(degree: int) -> None:
    rgb = torch.tensor([[0.2, 0.5, 0.9], [1.3, 0.0, 0.7]], dtype=F64)  # [2, 3]
    coeffs = torch.zeros(2, num_sh_coeffs(degree), 3, dtype=F64)
    coeffs[:, 0] = rgb_to_sh_dc(rgb)
    dirs = _random_dirs(100, seed=6)[:, None, :]  # [100, 1, 3], broadcast against [2, K, 3]
    out = sh_to_rgb(degree, coeffs, dirs)
    assert out.shape == (100, 2, 3)
    torch.testing.assert_close(out, rgb.expand(100, 2, 3), rtol=0, atol=1e-14)


def test_colour_is_basis_times_coeffs_and_clamped() -> None:
    n = 64
    dirs = _random_dirs(n, seed=7)
    coeffs = torch.randn(n, 16, 3, generator=_generator(8), dtype=F64)
    expected = torch.einsum("nk,nkc->nc", _textbook_real_sh(dirs) * _gsplat_signs(), coeffs) + 0.5
    out = sh_to_rgb(3, coeffs, dirs)
    assert (expected < 0).any(), "test needs some negative colours to exercise the clamp"
    torch.testing.assert_close(out, expected.clamp_min(0.0), rtol=1e-12, atol=1e-12)


def test_colour_uses_only_first_coefficients() -> None:
    dirs = _random_dirs(10, seed=9)
    coeffs = torch.randn(10, 16, 3, generator=_generator(10), dtype=F64)
    for degree in DEGREES:
        k = num_sh_coeffs(degree)
        torch.testing.assert_close(sh_to_rgb(degree, coeffs, dirs), sh_to_rgb(degree, coeffs[:, :k], dirs))
    with pytest.raises(ValueError, match="needs 9 coefficients"):
        sh_to_rgb(2, coeffs[:, :4], dirs)


def test_rgb_dc_conversions_are_inverse() -> None:
    rgb = np.array([0.0, 0.25, 0.5, 1.0])
    np.testing.assert_allclose(rgb_to_sh_dc(rgb), (rgb - 0.5) / 0.28209479177387814)
    np.testing.assert_allclose(sh_dc_to_rgb(rgb_to_sh_dc(rgb)), rgb, atol=1e-15)
    t = torch.rand(5, 3, generator=_generator(11), dtype=F64)
    torch.testing.assert_close(sh_dc_to_rgb(rgb_to_sh_dc(t)), t)
    assert rgb_to_sh_dc(0.5) == 0.0


# --- gradients --------------------------------------------------------------------------


@pytest.mark.parametrize("degree", DEGREES)
def test_colour_gradients_match_finite_differences(degree: int) -> None:
    n, k = 6, num_sh_coeffs(degree)
    dirs = _random_dirs(n, seed=12).requires_grad_(True)
    coeffs = 0.1 * torch.randn(n, k, 3, generator=_generator(13), dtype=F64)
    coeffs[:, 0] = rgb_to_sh_dc(torch.full((n, 3), 0.6, dtype=F64))  # colours > 0: away from the clamp
    coeffs.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda c, d: sh_to_rgb(degree, c, d), (coeffs, dirs))


def test_basis_and_rotation_gradients_match_finite_differences() -> None:
    dirs = _random_dirs(5, seed=14).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda d: sh_basis(3, d), (dirs,))
    rots = torch.stack([_random_rotation(s) for s in range(5)]).requires_grad_(True)
    assert torch.autograd.gradcheck(rotate_view_dirs, (dirs, rots))


# --- rotations --------------------------------------------------------------------------


def test_rotate_view_dirs_applies_transpose() -> None:
    rots = torch.stack([_random_rotation(s) for s in range(20, 30)])  # [10, 3, 3]
    d_world = _random_dirs(10, seed=15)
    d_canon = rotate_view_dirs(d_world, rots)
    torch.testing.assert_close(d_canon, torch.stack([r.T @ d for r, d in zip(rots, d_world)]))
    # Round trip: R (R^T d) = d; lengths are kept.
    torch.testing.assert_close(torch.einsum("nij,nj->ni", rots, d_canon), d_world)
    torch.testing.assert_close(d_canon.norm(dim=-1), d_world.norm(dim=-1))
    # 90 degrees about z maps canonical +x to world +y, so world +y is canonical +x.
    rz = torch.tensor([[[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]], dtype=F64)
    torch.testing.assert_close(rotate_view_dirs(torch.tensor([[0.0, 1.0, 0.0]], dtype=F64), rz),
                               torch.tensor([[1.0, 0.0, 0.0]], dtype=F64))
    with pytest.raises(ValueError, match="rotations"):
        rotate_view_dirs(d_world, rots[:, :2])


def _rotate_degree1_coeffs(coeffs: torch.Tensor, rot: torch.Tensor) -> torch.Tensor:
    """Degree-1 coefficients [..., 3, C] (order y, z, x with 3DGS signs) of the field
    d -> f(R^T d), where f has coefficients ``coeffs``.

    f(d) = C1 * v . d with v = (-c_x, -c_y, c_z) built from the coefficients stored as
    (c_y, c_z, c_x) = (coeffs[0], coeffs[1], coeffs[2]); then f(R^T d) = C1 * (R v) . d.
    """
    c_y, c_z, c_x = coeffs.unbind(-2)
    v = torch.stack([-c_x, -c_y, c_z], dim=-2)  # [..., 3 (xyz), C]
    v_rot = torch.einsum("ij,...jc->...ic", rot, v)
    return torch.stack([-v_rot[..., 1, :], v_rot[..., 2, :], -v_rot[..., 0, :]], dim=-2)


def test_degree1_field_rotates_with_directions() -> None:
    """Rotating the SH field by R and the direction by R leaves the colour unchanged."""
    coeffs = torch.randn(32, 4, 3, generator=_generator(16), dtype=F64)
    coeffs[:, 0] = 4.0  # colours > 0 so the clamp does not hide anything
    dirs = _random_dirs(32, seed=17)
    for seed in range(5):
        rot = _random_rotation(100 + seed)
        rotated = coeffs.clone()
        rotated[:, 1:4] = _rotate_degree1_coeffs(coeffs[:, 1:4], rot)
        torch.testing.assert_close(sh_to_rgb(1, rotated, dirs @ rot.T), sh_to_rgb(1, coeffs, dirs))
        # The same with rotate_view_dirs: evaluating the canonical field at R^T d_world
        # equals evaluating the world (rotated) field at d_world.
        d_canon = rotate_view_dirs(dirs, rot.expand(32, 3, 3))
        torch.testing.assert_close(sh_to_rgb(1, coeffs, d_canon), sh_to_rgb(1, rotated, dirs))


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_each_band_is_closed_under_rotation(degree: int) -> None:
    """For every band l, Y_l(R^T d) = D Y_l(d) for an orthogonal D (a Wigner matrix in
    this basis); D is fitted by least squares on quadrature points, the fit must be exact
    and D orthogonal. A wrong polynomial or constant breaks this."""
    dirs, _ = _sphere_quadrature()
    lo, hi = degree**2, (degree + 1) ** 2
    for seed in range(3):
        rot = _random_rotation(200 + seed)
        band = sh_basis(degree, dirs)[:, lo:hi]  # [Q, 2l+1]
        band_rot = sh_basis(degree, dirs @ rot)[:, lo:hi]  # rows: Y_l(R^T d)
        d_t = torch.linalg.lstsq(band, band_rot).solution  # band @ d_t ~ band_rot
        torch.testing.assert_close(band @ d_t, band_rot, rtol=0, atol=1e-12)
        torch.testing.assert_close(d_t.T @ d_t, torch.eye(hi - lo, dtype=F64), rtol=0, atol=1e-12)
