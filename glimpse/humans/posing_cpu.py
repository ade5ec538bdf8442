"""Posing a person's canonical Gaussians for training by the C++ kernel (csrc/skinning_cpu.cpp), with its
hand-written backward: the same maths as PersonGaussians.posed_with's PyTorch path (skin weights from the
grid, blended transforms, A mu, L Sigma Lᵀ, view directions into the canonical frame), in one pass per
Gaussian instead of an autograd graph of small batched kernels."""

from __future__ import annotations

import torch
from torch import Tensor

from glimpse.body.skinning import SkinWeightGrid


class _SkinCPU(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means: Tensor, covariances: Tensor, posed: Tensor, grid: SkinWeightGrid, canonical: Tensor,
                centre: Tensor):
        from glimpse.render.composite_cpu import extension

        tensors = [t.detach().float().contiguous() for t in (
            means, covariances, grid.joints_last, torch.stack([grid.bounds_min, grid.bounds_max]), posed, canonical,
            centre)]
        ctx.save_for_backward(*tensors)
        return tuple(extension().skin_forward(*tensors))

    @staticmethod
    def backward(ctx, v_means: Tensor, v_covariances: Tensor, v_dirs: Tensor):
        from glimpse.render.composite_cpu import extension

        grads = extension().skin_backward(*ctx.saved_tensors, v_means.float(), v_covariances.float(), v_dirs.float())
        return (*grads, None, None, None)


def pose_gaussians_cpu(means: Tensor, covariances: Tensor, posed: Tensor, grid: SkinWeightGrid, canonical: Tensor,
                       camera_centre: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Canonical means [N, 3] and covariances [N, 3, 3], the frame's joint transforms ``posed [J, 4, 4]`` and
    the canonical ones [J, 4, 4] -> posed means [N, 3], posed covariances [N, 3, 3] and the view directions
    from ``camera_centre [3]`` rotated into each Gaussian's canonical frame [N, 3]; differentiable in means,
    covariances and ``posed``."""
    return _SkinCPU.apply(means, covariances, posed, grid, canonical, camera_centre)
