"""The SSIM map of :func:`glimpse.metrics.image.ssim_map`, fused in C++ for the training losses on the CPU.

PyTorch builds the map from about fifty whole-image operations forward and backward (five moment maps
concatenated and padded, two blurs, a dozen element-wise products); on a 320x240 frame they cost a stage-04
iteration about a fifth of its time. ``glimpse/render/csrc/ssim_cpu.cpp`` computes the same map and its gradient
with respect to the first image in a few passes; the metrics tables take their maps from it too (stage 07 scores
fourteen of them per held-out view). ``tests/test_metrics.py`` compares the PyTorch form with scikit-image, and
``tests/test_ssim_cpu.py`` the two forms, values and gradients.
"""

from __future__ import annotations

import torch
from torch import Tensor

from glimpse.metrics.image import SSIM_C1, SSIM_C2, SSIM_WIN_SIZE, gaussian_window_1d, ssim_map, ssim_of_map
from glimpse.render.composite_cpu import extension, kernel_applies


class _SsimMap(torch.autograd.Function):
    @staticmethod
    def forward(ctx, pred: Tensor, target: Tensor) -> Tensor:
        taps = gaussian_window_1d()
        images = [t.detach().reshape(-1, *t.shape[-3:]).contiguous() for t in (pred, target)]
        full, moments = extension().ssim_forward(*images, taps, SSIM_C1, SSIM_C2)
        ctx.save_for_backward(*images, moments, taps)
        return full.reshape(pred.shape)

    @staticmethod
    def backward(ctx, grad_map: Tensor):
        pred, target, moments, taps = ctx.saved_tensors
        grad = extension().ssim_backward(grad_map.reshape(pred.shape).float().contiguous(), pred, target, moments,
                                         taps, SSIM_C1, SSIM_C2)
        return grad.reshape(grad_map.shape), None


def fused_ssim_applies(pred: Tensor, target: Tensor) -> bool:
    """Whether the C++ form can compute this map: float32 CPU images of one shape ``[..., H, W, C]`` of at least
    the window's size, a target that needs no gradient, and a kernel that builds here."""
    return (pred.shape == target.shape and pred.ndim >= 3 and min(pred.shape[-3:-1]) >= SSIM_WIN_SIZE
            and not target.requires_grad and kernel_applies(pred, target))


def ssim_map_for_loss(pred: Tensor, target: Tensor) -> Tensor:
    """``ssim_map(pred, target)``, by the fused C++ kernel where it applies, else by PyTorch."""
    return _SsimMap.apply(pred, target) if fused_ssim_applies(pred, target) else ssim_map(pred, target)


@torch.no_grad()
def ssim_fused(pred: Tensor, target: Tensor, mask: Tensor | None = None) -> Tensor:
    """``glimpse.metrics.image.ssim(pred, target, mask)``, its map by the fused C++ kernel where it applies."""
    return ssim_of_map(ssim_map_for_loss(pred, target), mask)
