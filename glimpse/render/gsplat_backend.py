"""gsplat's CUDA rasterizer behind Glimpse's `rasterize` (optional extra ``[cuda]``).

Only ever called with CUDA tensors: gsplat's wrappers try to build CUDA code when
given CPU tensors. gsplat samples pixel centres at (i + 0.5), Glimpse (OpenCV) at
i, so the principal point is shifted by +0.5 on the way in (CONTRACTS.md). The
composited channels are Glimpse's (colour, ones, depth, group indicators), so the
outputs mean the same as the other backends'.

On CUDA tensors the covariances and spherical harmonics are computed by gsplat's fused kernels too
(:func:`gsplat_ops_apply`): done by PyTorch there they are dozens of small kernel launches each, and a
training iteration on a GPU is bound by launches, not by the GPU's work (docs/speed.md).
"""

from __future__ import annotations

import torch
from torch import Tensor

from glimpse.errors import GlimpseError
from glimpse.render.projection import LOW_PASS, Camera, Projected

GSPLAT_PIXEL_OFFSET = 0.5
SH_CHANNELS = 3  # gsplat's spherical_harmonics evaluates RGB coefficients only


def _gsplat_ops():
    """gsplat's CUDA wrappers (gsplat.cuda._wrapper), or None when gsplat is not installed."""
    try:
        from gsplat.cuda import _wrapper
    except ImportError:
        return None
    return _wrapper


def gsplat_ops_apply(*tensors: Tensor) -> bool:
    """Whether gsplat's fused kernels can compute on ``tensors``: all float32 on CUDA, and gsplat installed."""
    return all(t.is_cuda and t.dtype == torch.float32 for t in tensors) and _gsplat_ops() is not None


def quat_scale_to_covariance_gsplat(quats: Tensor, scales: Tensor) -> Tensor:
    """quats [N, 4] wxyz (any length), scales [N, 3] -> covariances [N, 3, 3] = R S Sᵀ Rᵀ, by gsplat's kernel."""
    covariances, _ = _gsplat_ops().quat_scale_to_covar_preci(quats, scales, compute_covar=True, compute_preci=False)
    return covariances


def sh_to_rgb_gsplat(degree: int, sh_coeffs: Tensor, dirs: Tensor) -> Tensor:
    """sh_coeffs [N, K, 3], dirs [N, 3] (any length) -> the 3DGS colour [N, 3] = max(SH(dirs) + 0.5, 0),
    by gsplat's kernel (the sum without the offset; gsplat adds it in its own rasterization)."""
    from glimpse.render.sh import MIN_RGB, RGB_OFFSET

    return torch.clamp_min(_gsplat_ops().spherical_harmonics(degree, dirs, sh_coeffs) + RGB_OFFSET, MIN_RGB)


def rasterize_gsplat(camera: Camera, means: Tensor, covariances: Tensor, opacities: Tensor, features: Tensor,
                     antialiased: bool) -> tuple[Tensor, Projected]:
    """Composite ``features`` [N, C] with gsplat; returns the image [H, W, C] and what it projected."""
    try:
        from gsplat import rasterization
    except ImportError:
        raise GlimpseError("render.backend=gsplat needs gsplat: on a CUDA machine, from this checkout, "
                           ".venv/bin/pip install -e '.[cuda]' (the cuda extra of pyproject.toml)") from None
    device = means.device
    K = camera.K.to(device=device, dtype=means.dtype).clone()
    K[0, 2] += GSPLAT_PIXEL_OFFSET
    K[1, 2] += GSPLAT_PIXEL_OFFSET
    viewmat = torch.eye(4, device=device, dtype=means.dtype)
    viewmat[:3, :3] = camera.R.to(viewmat)
    viewmat[:3, 3] = camera.t.to(viewmat)
    image, _, meta = rasterization(
        means=means, quats=None, scales=None, covars=covariances, opacities=opacities, colors=features,
        viewmats=viewmat[None], Ks=K[None], width=camera.width, height=camera.height,
        near_plane=camera.near, far_plane=camera.far, eps2d=LOW_PASS, packed=False,
        rasterize_mode="antialiased" if antialiased else "classic", render_mode="RGB",
    )
    radii = meta["radii"][0]
    radii = radii.max(dim=-1).values if radii.ndim == 2 else radii  # newer gsplat: per-axis radii
    means2d = meta["means2d"][0]
    projected = Projected(
        means2d=means2d, conics=meta["conics"][0], depths=meta["depths"][0], opacities=opacities,
        radii=radii.to(torch.int32), extents=torch.zeros_like(means2d), visible=radii > 0,
    )
    return image[0], projected
