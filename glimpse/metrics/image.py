"""Image quality metrics: PSNR and SSIM, optionally inside a mask; differentiable in torch.

Conventions (the whole project):

- images are float tensors ``[..., H, W, 3]`` (channel last) with values in ``[0, 1]``
  (data range 1); any leading batch dimensions are kept in the result;
- masks are ``[..., H, W]`` bool or float tensors (1 = inside); float masks weight pixels;
- a metric returns one value per image, shape ``[...]`` (a 0-d tensor for one image).

SSIM follows scikit-image's ``structural_similarity(im1, im2, gaussian_weights=True,
sigma=1.5, use_sample_covariance=False, data_range=1.0, channel_axis=-1)``: an 11x11
Gaussian window (sigma 1.5, truncated at 3.5 sigma), K1 = 0.01, K2 = 0.03, population
(co)variances, the SSIM map computed with symmetric ("reflect" in scipy) padding, and the
mean taken over the map with a ``(11 - 1) / 2 = 5`` pixel strip removed at every border,
then over the channels. The masked variant averages the full map inside the mask instead
(no border strip: the mask chooses the pixels).

LPIPS lives in :mod:`glimpse.metrics.lpips`; losses in :mod:`glimpse.metrics.losses`; the table writer in
:mod:`glimpse.metrics.table`.
"""

from __future__ import annotations

from typing import Literal, overload

import torch
import torch.nn.functional as F
from torch import Tensor

DATA_RANGE = 1.0  # images are in [0, 1]
SSIM_SIGMA = 1.5  # Gaussian window std (pixels), Wang et al. 2004
SSIM_TRUNCATE = 3.5  # scikit-image truncates its Gaussian at 3.5 sigma when gaussian_weights=True
SSIM_RADIUS = int(SSIM_TRUNCATE * SSIM_SIGMA + 0.5)  # 5, as scipy.ndimage rounds it
SSIM_WIN_SIZE = 2 * SSIM_RADIUS + 1  # 11
SSIM_K1 = 0.01
SSIM_K2 = 0.03
SSIM_C1 = (SSIM_K1 * DATA_RANGE) ** 2
SSIM_C2 = (SSIM_K2 * DATA_RANGE) ** 2
PSNR_MIN_MSE = 1e-10  # MSE floor so identical images give a finite PSNR (100 dB)


def _check_images(pred: Tensor, target: Tensor) -> None:
    if pred.shape != target.shape:
        raise ValueError(f"pred and target shapes differ: {tuple(pred.shape)} vs {tuple(target.shape)}")
    if pred.ndim < 3:
        raise ValueError(f"images must be [..., H, W, C], found shape {tuple(pred.shape)}")


def _mask_weights(mask: Tensor, image: Tensor) -> Tensor:
    """Mask ``[..., H, W]`` as float weights ``[..., H, W, 1]`` on the image's device and dtype."""
    if mask.shape != image.shape[:-1]:
        raise ValueError(f"mask must be [..., H, W] = {tuple(image.shape[:-1])}, found {tuple(mask.shape)}")
    return mask.to(device=image.device, dtype=image.dtype).unsqueeze(-1)


def masked_mean(values: Tensor, mask: Tensor | None) -> Tensor:
    """Mean of ``values [..., H, W, C]`` over H, W, C, restricted to ``mask [..., H, W]``.

    Returns ``[...]``. An empty mask gives NaN (there is nothing to average).
    """
    if mask is None:
        return values.mean(dim=(-3, -2, -1))
    weights = _mask_weights(mask, values)
    total = (values * weights).sum(dim=(-3, -2, -1))
    count = weights.sum(dim=(-3, -2, -1)) * values.shape[-1]
    return total / count


def psnr(pred: Tensor, target: Tensor, mask: Tensor | None = None) -> Tensor:
    """Peak signal-to-noise ratio in dB for images in [0, 1].

    pred, target: ``[..., H, W, C]``; mask: optional ``[..., H, W]`` (MSE over masked pixels
    and all channels only). Returns ``[...]``; the MSE is floored at ``PSNR_MIN_MSE``.
    """
    _check_images(pred, target)
    mse = masked_mean((pred - target) ** 2, mask)
    return 10.0 * torch.log10(DATA_RANGE**2 / mse.clamp_min(PSNR_MIN_MSE))


def gaussian_window_1d(dtype: torch.dtype = torch.float32, device: torch.device | None = None) -> Tensor:
    """The normalised 1-D Gaussian taps ``[SSIM_WIN_SIZE]`` of scipy.ndimage.gaussian_filter."""
    offsets = torch.arange(-SSIM_RADIUS, SSIM_RADIUS + 1, dtype=torch.float64)
    taps = torch.exp(-0.5 * (offsets / SSIM_SIGMA) ** 2)
    return (taps / taps.sum()).to(dtype=dtype, device=device)


def _symmetric_pad(x: Tensor, pad: int) -> Tensor:
    """Pad the last two dims of ``x [N, C, H, W]`` by mirroring with the edge repeated.

    This is scipy.ndimage's ``mode="reflect"`` (``d c b a | a b c d``), which torch's
    ``F.pad`` lacks; needs ``pad <= min(H, W)``.
    """
    x = torch.cat([x[..., :pad, :].flip(-2), x, x[..., -pad:, :].flip(-2)], dim=-2)
    return torch.cat([x[..., :pad].flip(-1), x, x[..., -pad:].flip(-1)], dim=-1)


def _gaussian_filter(x: Tensor) -> Tensor:
    """Separable Gaussian blur of every channel of ``x [N, C, H, W]``, same size out."""
    channels = x.shape[1]
    taps = gaussian_window_1d(x.dtype, x.device)
    x = _symmetric_pad(x, SSIM_RADIUS)
    x = F.conv2d(x, taps.view(1, 1, 1, -1).expand(channels, 1, 1, -1), groups=channels)
    return F.conv2d(x, taps.view(1, 1, -1, 1).expand(channels, 1, -1, 1), groups=channels)


def ssim_map(pred: Tensor, target: Tensor) -> Tensor:
    """Per-pixel, per-channel SSIM ``[..., H, W, C]`` (scikit-image's ``full=True`` map).

    pred, target: ``[..., H, W, C]`` in [0, 1] with ``H, W >= 11`` (scikit-image's limit).
    """
    _check_images(pred, target)
    *batch, height, width, channels = pred.shape
    if min(height, width) < SSIM_WIN_SIZE:
        raise ValueError(f"SSIM needs images of at least {SSIM_WIN_SIZE}x{SSIM_WIN_SIZE}, found {height}x{width}")
    x = pred.reshape(-1, height, width, channels).permute(0, 3, 1, 2)
    y = target.reshape(-1, height, width, channels).permute(0, 3, 1, 2).to(x.dtype)
    # One blur for all five moments: [N, 5C, H, W].
    moments = _gaussian_filter(torch.cat([x, y, x * x, y * y, x * y], dim=1))
    mu_x, mu_y, mu_xx, mu_yy, mu_xy = moments.split(channels, dim=1)
    var_x = mu_xx - mu_x * mu_x
    var_y = mu_yy - mu_y * mu_y
    cov_xy = mu_xy - mu_x * mu_y
    numerator = (2 * mu_x * mu_y + SSIM_C1) * (2 * cov_xy + SSIM_C2)
    denominator = (mu_x * mu_x + mu_y * mu_y + SSIM_C1) * (var_x + var_y + SSIM_C2)
    full = numerator / denominator
    return full.permute(0, 2, 3, 1).reshape(*batch, height, width, channels)


@overload
def ssim(pred: Tensor, target: Tensor, mask: Tensor | None = None, return_map: Literal[False] = False) -> Tensor: ...


@overload
def ssim(
    pred: Tensor, target: Tensor, mask: Tensor | None = None, *, return_map: Literal[True]
) -> tuple[Tensor, Tensor]: ...


def ssim(
    pred: Tensor, target: Tensor, mask: Tensor | None = None, return_map: bool = False
) -> Tensor | tuple[Tensor, Tensor]:
    """Mean SSIM per image, ``[...]``, matching scikit-image (see the module docstring).

    Without a mask: mean over the map less a 5-pixel border, then over channels.
    With ``mask [..., H, W]``: mean of the full map over the masked pixels and channels.
    ``return_map=True`` also returns the full map ``[..., H, W, C]``.
    """
    full = ssim_map(pred, target)
    value = ssim_of_map(full, mask)
    return (value, full) if return_map else value


def ssim_of_map(full: Tensor, mask: Tensor | None = None) -> Tensor:
    """``ssim``'s value from the full map ``[..., H, W, C]``: without a mask, its mean less a 5-pixel border; with
    ``mask [..., H, W]``, its mean over the masked pixels and channels."""
    if mask is None:
        r = SSIM_RADIUS
        return full[..., r:-r, r:-r, :].mean(dim=(-3, -2, -1))
    return masked_mean(full, mask)

