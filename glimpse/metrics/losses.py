"""Training losses: L1, MSE, D-SSIM, LPIPS and the hard-surface alpha regulariser.

Shapes follow :mod:`glimpse.metrics.image`: images ``[..., H, W, 3]`` in [0, 1], masks
``[..., H, W]`` (bool or float weights). Every loss returns a 0-d tensor, the mean over
everything it covers; with a mask, the mean over the masked pixels of the whole batch (pixel
losses, D-SSIM, hard surface; so an image weighs by its masked area) or over images with both
inputs zeroed outside the mask (LPIPS, the official code's convention).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from glimpse.metrics.image import SSIM_RADIUS
from glimpse.metrics.lpips import LPIPS
from glimpse.metrics.ssim_cpu import ssim_map_for_loss

# -log(exp(-a) + exp(a - 1)) is smallest at a = 0 and a = 1, where it equals -log(1 + e^-1);
# adding log(1 + e^-1) = 0.31326... makes the minimum exactly 0 (LOLNeRF; the authors' code
# adds the rounded 0.313 in `denisty_reg_loss`). Its maximum, at a = 0.5, is then
# log(1 + e^-1) - log(2 e^-0.5) = 0.12011...
HARD_SURFACE_OFFSET = math.log1p(math.exp(-1.0))


def _pooled_mean(values: Tensor, mask: Tensor | None) -> Tensor:
    """Mean of ``values [..., H, W, C]`` over everything, or over the pixels of ``mask [..., H, W]``."""
    if mask is None:
        return values.mean()
    if mask.shape != values.shape[:-1]:
        raise ValueError(f"mask must be {tuple(values.shape[:-1])}, found {tuple(mask.shape)}")
    weights = mask.to(device=values.device, dtype=values.dtype).unsqueeze(-1)
    return (values * weights).sum() / (weights.sum() * values.shape[-1])


def l1_loss(pred: Tensor, target: Tensor, mask: Tensor | None = None) -> Tensor:
    """Mean absolute error over all pixels and channels (or over the masked pixels)."""
    return _pooled_mean((pred - target).abs(), mask)


def mse_loss(pred: Tensor, target: Tensor, mask: Tensor | None = None) -> Tensor:
    """Mean squared error over all pixels and channels (or over the masked pixels)."""
    return _pooled_mean((pred - target) ** 2, mask)


def dssim_loss(pred: Tensor, target: Tensor, mask: Tensor | None = None) -> Tensor:
    """``1 - SSIM`` (scikit-image protocol, see :func:`glimpse.metrics.image.ssim`), mean over images.

    Without a mask: 1 - mean of the SSIM map less its 5-pixel border (scikit-image's mean);
    with one: 1 - mean of the full map over the masked pixels. Images need H, W >= 11.
    """
    full = ssim_map_for_loss(pred, target)
    if mask is None:
        return 1.0 - full[..., SSIM_RADIUS:-SSIM_RADIUS, SSIM_RADIUS:-SSIM_RADIUS, :].mean()
    return 1.0 - _pooled_mean(full, mask)


def dssim_loss_on(pred: Tensor, target: Tensor, keep: Tensor) -> Tensor:
    """D-SSIM over the pixels of ``keep [H, W]`` (bool) of ``pred, target [H, W, 3]``. Pixels outside
    ``keep`` are set to the (detached) render in both images first, so what lies there (people for the
    background, a static occluder for a person) never enters an SSIM window."""
    inside = keep[..., None]
    filler = pred.detach()
    return dssim_loss(torch.where(inside, pred, filler)[None], torch.where(inside, target, filler)[None], keep[None])


def lpips_loss(lpips_module: LPIPS, pred: Tensor, target: Tensor, mask: Tensor | None = None) -> Tensor:
    """Mean LPIPS distance (raw, not x100) over the batch.

    pred, target: ``[B, H, W, 3]`` or ``[H, W, 3]``; mask: optional ``[B, H, W]`` / ``[H, W]``:
    both images are multiplied by it (black outside) before LPIPS.
    """
    return lpips_module(_lpips_masked(pred, mask), _lpips_masked(target, mask)).mean()


def lpips_loss_target(lpips_module: LPIPS, target: Tensor, mask: Tensor | None = None) -> list[Tensor]:
    """The target's side of ``lpips_loss`` for one ``target [H, W, 3]`` (and ``mask [H, W]``): its LPIPS
    features, computed once for a target the loss meets again and again (``lpips_loss_to_features``)."""
    return lpips_module.target_features(_lpips_masked(target, mask))


def lpips_loss_to_features(lpips_module: LPIPS, pred: Tensor, target_features: list[Tensor],
                           mask: Tensor | None = None) -> Tensor:
    """``lpips_loss`` of one ``pred [H, W, 3]`` against the target whose ``lpips_loss_target`` (with the same
    ``mask``) these features are: the same value, to the bit."""
    return lpips_module.distance_to_features(_lpips_masked(pred, mask), target_features)


def _lpips_masked(image: Tensor, mask: Tensor | None) -> Tensor:
    """``image [..., H, W, 3]`` black outside ``mask [..., H, W]`` (unchanged without one)."""
    if mask is None:
        return image
    if mask.shape != image.shape[:-1]:
        raise ValueError(f"mask must be {tuple(image.shape[:-1])}, found {tuple(mask.shape)}")
    return image * mask.to(device=image.device, dtype=image.dtype).unsqueeze(-1)


def hard_surface(alpha: Tensor) -> Tensor:
    """Element-wise ``-log(exp(-a) + exp(a - 1)) + HARD_SURFACE_OFFSET``, 0 at a in {0, 1}.

    Pushes each alpha towards 0 or 1 (not only up, unlike the paper's printed Eq. 12). Meant
    for alpha in [0, 1]: outside that range it goes negative and would push alpha further out.
    """
    return HARD_SURFACE_OFFSET - torch.logaddexp(-alpha, alpha - 1.0)


def hard_surface_loss(alpha: Tensor, mask: Tensor | None = None) -> Tensor:
    """Mean of :func:`hard_surface` over all of ``alpha`` (any shape, e.g. ``[..., H, W]``
    or per-Gaussian ``[N]``) or over the elements where ``mask`` (same shape) is set."""
    values = hard_surface(alpha)
    if mask is None:
        return values.mean()
    if mask.shape != alpha.shape:
        raise ValueError(f"mask must have alpha's shape {tuple(alpha.shape)}, found {tuple(mask.shape)}")
    weights = mask.to(device=alpha.device, dtype=alpha.dtype)
    return (values * weights).sum() / weights.sum()
