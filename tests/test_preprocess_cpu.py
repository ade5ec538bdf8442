"""The C++ per-Gaussian kernels (covariances from rotations and scales, SH colours) against their PyTorch
references: values, and gradients of a random loss through both."""

from __future__ import annotations

import pytest
import torch

from glimpse.render.composite_cpu import available as cpu_available
from glimpse.render.projection import quat_scale_to_covariance, quat_scale_to_covariance_torch
from glimpse.render.sh import MAX_SH_DEGREE, num_sh_coeffs, sh_to_rgb, sh_to_rgb_torch

pytestmark = pytest.mark.skipif(not cpu_available(), reason="the C++ kernel does not build here")
GRAD_REL = 1e-5


def grads_through(function, inputs: list[torch.Tensor], seed: int) -> tuple[torch.Tensor, list[torch.Tensor]]:
    leaves = [t.clone().requires_grad_(True) for t in inputs]
    out = function(*leaves)
    weights = torch.randn(out.shape, generator=torch.Generator().manual_seed(seed))
    (out * weights).sum().backward()
    return out.detach(), [leaf.grad for leaf in leaves]


def assert_close_relative(reference: torch.Tensor, other: torch.Tensor, name: str, tolerance: float = GRAD_REL) -> None:
    rel = float((reference - other).norm() / reference.norm().clamp(min=1e-30))
    assert rel < tolerance, f"{name}: relative L2 {rel:.2e}"


def test_covariances_and_their_gradients_match_the_reference():
    g = torch.Generator().manual_seed(0)
    quats = torch.randn(500, 4, generator=g) * torch.rand(500, 1, generator=g) * 3  # unnormalised, any length
    quats[0] = 0.0  # a zero quaternion: both normalise it to zero (torch's eps)
    scales = torch.exp(torch.randn(500, 3, generator=g) * 2 - 3)
    ref, ref_grads = grads_through(quat_scale_to_covariance_torch, [quats, scales], seed=1)
    out, grads = grads_through(quat_scale_to_covariance, [quats, scales], seed=1)
    torch.testing.assert_close(out, ref, rtol=1e-5, atol=1e-7)
    for name, a, b in zip(("quats", "scales"), ref_grads, grads):
        assert_close_relative(a[1:], b[1:], name)
    torch.testing.assert_close(grads[0][0], ref_grads[0][0], rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("degree", range(MAX_SH_DEGREE + 1))
def test_sh_colours_and_their_gradients_match_the_reference(degree):
    g = torch.Generator().manual_seed(degree)
    coeffs = torch.randn(400, 16, 3, generator=g) * 0.6  # some colours clamp at 0
    dirs = torch.randn(400, 3, generator=g) * torch.rand(400, 1, generator=g) * 5
    ref, ref_grads = grads_through(lambda c, d: sh_to_rgb_torch(degree, c, d), [coeffs, dirs], seed=2)
    out, grads = grads_through(lambda c, d: sh_to_rgb(degree, c, d), [coeffs, dirs], seed=2)
    assert (ref == 0).any() and (ref > 0).any()
    torch.testing.assert_close(out, ref, rtol=1e-5, atol=1e-6)
    assert_close_relative(ref_grads[0], grads[0], "coefficients")
    assert torch.count_nonzero(grads[0][:, num_sh_coeffs(degree):]) == 0  # coefficients above the degree
    if degree > 0:  # at degree 0 the colour does not depend on the direction: both gradients are 0
        assert_close_relative(ref_grads[1], grads[1], "directions")
    else:
        assert torch.count_nonzero(grads[1]) == 0


def test_sh_of_a_sliced_model_and_other_shapes_fall_back_or_agree():
    coeffs = torch.randn(50, 16, 3)
    dirs = torch.randn(50, 3)
    torch.testing.assert_close(sh_to_rgb(2, coeffs[:, :9], dirs), sh_to_rgb_torch(2, coeffs[:, :9], dirs))
    batched = torch.randn(4, 50, 16, 3)  # leading batch dimensions: the PyTorch path
    torch.testing.assert_close(sh_to_rgb(3, batched, dirs), sh_to_rgb_torch(3, batched, dirs))
    double = coeffs.double()  # float64: the PyTorch path, in float64
    assert sh_to_rgb(3, double, dirs.double()).dtype == torch.float64
