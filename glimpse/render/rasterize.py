"""`rasterize`: one differentiable Gaussian-splatting call, three backends.

    out = rasterize(camera, means=..., opacities=..., quats=..., scales=..., sh=..., background=...,
                    settings=RenderConfig(backend="auto", sh_degree=3, antialiased=False))
    out.rgb [H, W, 3], out.alpha [H, W], out.depth [H, W], out.group_alpha [G, H, W]

Backends (``settings.backend``): "cpu" (C++ tile compositing, hand-written
backward), "torch" (pure PyTorch, the reference and the fallback where no
compiler exists), "gsplat" (gsplat's CUDA kernels, for CUDA tensors). "auto"
picks gsplat for CUDA tensors, else cpu when its kernel builds, else torch.

Projection, tile binning and colours are computed here in PyTorch and shared by
the cpu and torch backends; only compositing differs. The compositor blends any
number of channels: colour, a channel of ones (its blend is the alpha), depth,
and one indicator channel per group (background, each person), whose blends are
the per-group alphas. Those sum to the alpha.
"""

from __future__ import annotations

from dataclasses import dataclass
import torch
from torch import Tensor

from glimpse.render.binning import bin_gaussians
from glimpse.render.config import Backend, RenderConfig
from glimpse.render.composite_torch import composite_torch
from glimpse.render.projection import (
    Camera, Projected, project_gaussians, project_gaussians_cpu, quat_scale_to_covariance,
    quat_scale_to_covariance_torch,
)
from glimpse.render.sh import sh_to_rgb, sh_to_rgb_torch

TILE_SIZE = 16  # pixels per tile side


@dataclass
class RenderOutput:
    """rgb [H, W, 3] (background blended in); alpha [H, W]; depth [H, W] (expected camera z of the
    Gaussians, 0 where alpha is 0); group_alpha [G, H, W] or None; means2d [N, 2] pixels (call
    means2d.retain_grad() before backward to read the screen-space gradients densification uses);
    radii [N] int32 3-sigma screen radius (0: not drawn); visible [N] bool; backend used."""

    rgb: Tensor
    alpha: Tensor
    depth: Tensor
    group_alpha: Tensor | None
    means2d: Tensor
    radii: Tensor
    visible: Tensor
    backend: str


def choose_backend(backend: Backend, device: torch.device) -> str:
    if backend != "auto":
        if backend == "gsplat" and device.type != "cuda":
            raise ValueError("render backend gsplat needs CUDA tensors (its wrappers try to build CUDA on CPU ones)")
        if backend in ("cpu", "torch") and device.type != "cpu":
            raise ValueError(f"render backend {backend} needs CPU tensors, found {device}")
        return backend
    if device.type == "cuda":
        return "gsplat"
    from glimpse.render import composite_cpu

    return "cpu" if composite_cpu.available() else "torch"


def _colours(camera: Camera, means: Tensor, colors: Tensor | None, sh: Tensor | None, sh_degree: int | None,
             view_dirs: Tensor | None, reference: bool) -> Tensor:
    """colors, or the SH colours along view_dirs (PyTorch's reference maths when ``reference``)."""
    if (colors is None) == (sh is None):
        raise ValueError("rasterize: give exactly one of colors [N, 3] and sh [N, K, 3]")
    if colors is not None:
        return colors
    degree = int(round(sh.shape[1] ** 0.5)) - 1 if sh_degree is None else sh_degree
    if view_dirs is None:  # from the camera centre to each Gaussian, in the world frame
        view_dirs = means - camera.centre.to(means)
    return (sh_to_rgb_torch if reference else sh_to_rgb)(degree, sh, view_dirs)


def _features(rgb: Tensor, depths: Tensor, groups: Tensor | None, num_groups: int) -> Tensor:
    """[N, 3 + 1 + 1 + G]: colour, one (alpha), depth, group indicators."""
    parts = [rgb, torch.ones_like(depths)[:, None], depths[:, None]]
    if groups is not None:
        parts.append(torch.nn.functional.one_hot(groups.long(), num_groups).to(rgb))
    return torch.cat(parts, dim=1)


def rasterize(
    camera: Camera, *, means: Tensor, opacities: Tensor,
    quats: Tensor | None = None, scales: Tensor | None = None, covariances: Tensor | None = None,
    colors: Tensor | None = None, sh: Tensor | None = None, sh_degree: int | None = None,
    view_dirs: Tensor | None = None, background: Tensor | None = None,
    groups: Tensor | None = None, num_groups: int | None = None,
    settings: RenderConfig,
) -> RenderOutput:
    """Render N Gaussians (world frame, metres) seen by ``camera``.

    means [N, 3]; opacities [N] in [0, 1]; either quats [N, 4] (wxyz) + scales [N, 3] (linear) or
    covariances [N, 3, 3] (a posed person's A Σ Aᵀ); either colors [N, 3] or sh [N, K, 3] with
    view_dirs [N, 3] (default: camera centre to mean; a posed person's caller rotates them into
    the canonical frame) and sh_degree (default from K); background [3] (default black);
    groups [N] int in [0, num_groups) for per-group alphas. ``settings`` (the pipeline's ``render`` section,
    passed whole so that every render path draws alike) picks the backend and the antialiasing.
    """
    name = choose_backend(settings.backend, means.device)
    if covariances is None:
        if quats is None or scales is None:
            raise ValueError("rasterize: give quats and scales, or covariances")
        covariances = (quat_scale_to_covariance_torch if name == "torch" else quat_scale_to_covariance)(quats, scales)
    rgb = _colours(camera, means, colors, sh, sh_degree, view_dirs, reference=name == "torch")
    if groups is not None and num_groups is None:
        num_groups = int(groups.max()) + 1 if len(groups) else 1
    if name == "gsplat":
        from glimpse.render.gsplat_backend import rasterize_gsplat

        depths = (means @ camera.R.to(means)[2] + camera.t.to(means)[2])  # camera z
        image, projected = rasterize_gsplat(camera, means, covariances, opacities,
                                            _features(rgb, depths, groups, num_groups or 0), settings.antialiased)
    else:
        project = project_gaussians_cpu if name == "cpu" else project_gaussians
        projected = project(means, covariances, opacities, camera, settings.antialiased)
        features = _features(rgb, projected.depths, groups, num_groups or 0)
        image = _composite(name, projected, features, camera)
    return _finish(image, projected, background, groups is not None, name)


def _composite(name: str, projected: Projected, features: Tensor, camera: Camera) -> Tensor:
    bins = bin_gaussians(projected.means2d.detach(), projected.extents, projected.depths.detach(),
                         projected.visible, camera.width, camera.height, TILE_SIZE, use_cpu_kernel=name == "cpu")
    if name == "cpu":
        from glimpse.render.composite_cpu import composite_cpu

        return composite_cpu(projected.means2d, projected.conics, projected.opacities, features,
                             projected.extents, bins, camera.width, camera.height)
    return composite_torch(projected.means2d, projected.conics, projected.opacities, features, bins,
                           camera.width, camera.height)


def _finish(image: Tensor, projected: Projected, background: Tensor | None, has_groups: bool,
            name: str) -> RenderOutput:
    alpha = image[..., 3]
    rgb = image[..., :3]
    if background is not None:
        rgb = rgb + (1.0 - alpha)[..., None] * background.to(rgb)
    depth = torch.where(alpha > 0, image[..., 4] / alpha.clamp(min=1e-12), torch.zeros_like(alpha))
    group_alpha = image[..., 5:].permute(2, 0, 1) if has_groups else None
    return RenderOutput(rgb=rgb, alpha=alpha, depth=depth, group_alpha=group_alpha, means2d=projected.means2d,
                        radii=projected.radii, visible=projected.visible, backend=name)
