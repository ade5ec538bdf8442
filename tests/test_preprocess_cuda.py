"""gsplat's fused per-Gaussian kernels (covariances, SH colours), which Glimpse uses for CUDA tensors, against
the PyTorch references: values, and gradients of a random loss through both. Runs only where a CUDA device
and gsplat are present (never a requirement of the suite)."""

from __future__ import annotations

import pytest
import torch

from glimpse.render.gsplat_backend import gsplat_ops_apply
from glimpse.render.projection import quat_scale_to_covariance, quat_scale_to_covariance_torch
from glimpse.render.sh import MAX_SH_DEGREE, sh_to_rgb, sh_to_rgb_torch
from tests.test_preprocess_cpu import assert_close_relative, grads_through

pytestmark = pytest.mark.skipif(not (torch.cuda.is_available() and gsplat_ops_apply(torch.zeros(1, device="cuda"))),
                                reason="no CUDA device with gsplat on this machine")
FUSED_MATH_REL = 1e-4  # gsplat builds with --use_fast_math (rsqrtf): a little looser than the C++ kernel's 1e-5


def cuda_grads_through(function, inputs: list[torch.Tensor], seed: int):
    """grads_through on CUDA copies of ``inputs`` (the random loss weights drawn on the CPU, as there)."""
    return grads_through(lambda *leaves: function(*[leaf.cuda() for leaf in leaves]).cpu(), inputs, seed)


def test_covariances_on_cuda_match_the_reference():
    g = torch.Generator().manual_seed(0)
    quats = torch.randn(500, 4, generator=g) * (0.1 + torch.rand(500, 1, generator=g) * 3)  # unnormalised
    scales = torch.exp(torch.randn(500, 3, generator=g) * 2 - 3)
    ref, ref_grads = grads_through(quat_scale_to_covariance_torch, [quats, scales], seed=1)
    out, grads = cuda_grads_through(quat_scale_to_covariance, [quats, scales], seed=1)
    torch.testing.assert_close(out, ref, rtol=1e-4, atol=1e-7)
    for name, a, b in zip(("quats", "scales"), ref_grads, grads):
        assert_close_relative(a, b, name, FUSED_MATH_REL)


@pytest.mark.parametrize("degree", range(MAX_SH_DEGREE + 1))
def test_sh_colours_on_cuda_match_the_reference(degree):
    g = torch.Generator().manual_seed(degree)
    coeffs = torch.randn(400, 16, 3, generator=g) * 0.6  # some colours clamp at 0
    dirs = torch.randn(400, 3, generator=g) * (0.1 + torch.rand(400, 1, generator=g) * 5)
    ref, ref_grads = grads_through(lambda c, d: sh_to_rgb_torch(degree, c, d), [coeffs, dirs], seed=2)
    out, grads = cuda_grads_through(lambda c, d: sh_to_rgb(degree, c, d), [coeffs, dirs], seed=2)
    assert (ref == 0).any() and (ref > 0).any()
    torch.testing.assert_close(out, ref, rtol=1e-4, atol=1e-5)
    assert_close_relative(ref_grads[0], grads[0], "coefficients", FUSED_MATH_REL)
    if degree > 0:  # at degree 0 the colour does not depend on the direction
        assert_close_relative(ref_grads[1], grads[1], "directions", FUSED_MATH_REL)
