"""The fused C++ SSIM map (glimpse/render/csrc/ssim_cpu.cpp) against the PyTorch one it replaces in the losses."""

from __future__ import annotations

import pytest
import torch

from glimpse.metrics.image import ssim, ssim_map
from glimpse.metrics.losses import dssim_loss, dssim_loss_on
from glimpse.metrics.ssim_cpu import _SsimMap, fused_ssim_applies, ssim_fused
from glimpse.render.composite_cpu import available

pytestmark = pytest.mark.skipif(not available(), reason="the C++ kernels do not build here")


def images(shape: tuple[int, ...], seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    target = torch.rand(shape, generator=generator)
    pred = (target + 0.2 * torch.randn(shape, generator=generator)).clamp(0, 1)  # related, as in training
    return pred, target


@pytest.mark.parametrize("shape", [(11, 11, 3), (2, 37, 29, 3), (48, 64, 1), (1, 1, 23, 40, 3)])
def test_values_and_gradient_match_pytorch(shape: tuple[int, ...]) -> None:
    pred, target = images(shape, seed=sum(shape))
    weights = torch.rand(shape, generator=torch.Generator().manual_seed(7))  # any upstream gradient
    fused_pred, torch_pred = pred.clone().requires_grad_(True), pred.clone().requires_grad_(True)
    fused = _SsimMap.apply(fused_pred, target)
    reference = ssim_map(torch_pred, target)
    torch.testing.assert_close(fused, reference, rtol=0, atol=2e-6)
    (fused * weights).sum().backward()
    (reference * weights).sum().backward()
    torch.testing.assert_close(fused_pred.grad, torch_pred.grad, rtol=1e-4, atol=1e-6)


def test_gradient_matches_finite_differences_in_float64_terms() -> None:
    """The adjoint blur folds the mirrored border back: check the pixels at the border against differences."""
    pred, target = images((13, 15, 1), seed=3)
    weights = torch.rand(13, 15, 1, generator=torch.Generator().manual_seed(4))
    pred.requires_grad_(True)
    (_SsimMap.apply(pred, target) * weights).sum().backward()
    step = 1e-3
    for y, x in [(0, 0), (0, 7), (4, 14), (12, 1), (6, 6)]:
        bumped = [pred.detach().double().clone() for _ in range(2)]
        bumped[0][y, x, 0] += step
        bumped[1][y, x, 0] -= step
        values = [float((ssim_map(b, target.double()) * weights.double()).sum()) for b in bumped]
        assert float(pred.grad[y, x, 0]) == pytest.approx((values[0] - values[1]) / (2 * step), rel=2e-3, abs=1e-5)


def test_losses_use_it_and_give_the_pytorch_values(monkeypatch) -> None:
    pred, target = images((40, 52, 3), seed=5)
    keep = torch.rand(40, 52, generator=torch.Generator().manual_seed(6)) > 0.3
    losses = {}
    for fused in (True, False):
        if not fused:
            monkeypatch.setattr("glimpse.metrics.ssim_cpu.fused_ssim_applies", lambda *_: False)
        leaf = pred.clone().requires_grad_(True)
        value = dssim_loss_on(leaf, target, keep) + dssim_loss(leaf[None], target[None])
        value.backward()
        losses[fused] = (value.detach(), leaf.grad)
    torch.testing.assert_close(losses[True][0], losses[False][0], rtol=0, atol=1e-6)
    torch.testing.assert_close(losses[True][1], losses[False][1], rtol=1e-4, atol=1e-7)


def test_falls_back_where_it_does_not_apply() -> None:
    pred, target = images((20, 20, 3), seed=8)
    assert fused_ssim_applies(pred, target)
    assert not fused_ssim_applies(pred.double(), target.double())
    assert not fused_ssim_applies(pred[:10], target[:10])  # smaller than the window
    target.requires_grad_(True)  # the fused form differentiates the first image only
    assert not fused_ssim_applies(pred, target)
    dssim_loss(pred, target).backward()
    assert target.grad is not None and target.grad.abs().sum() > 0


def test_the_metrics_ssim_is_the_pytorch_value_with_and_without_a_mask() -> None:
    """The tables score SSIM from the fused map (ssim_fused): the same values as glimpse.metrics.image.ssim, which
    tests/test_metrics.py holds to scikit-image."""
    pred, target = images((2, 45, 61, 3), seed=8)
    mask = torch.rand(2, 45, 61, generator=torch.Generator().manual_seed(9)) > 0.6
    assert fused_ssim_applies(pred, target)
    for region in (None, mask):
        torch.testing.assert_close(ssim_fused(pred, target, region), ssim(pred, target, region), rtol=0, atol=1e-6)
