"""gsplat's CUDA rasterizer behind Glimpse's `rasterize` (optional extra ``[cuda]``).

Only ever called with CUDA tensors: gsplat's wrappers try to build CUDA code when
given CPU tensors. gsplat samples pixel centres at (i + 0.5), Glimpse (OpenCV) at
i, so the principal point is shifted by +0.5 on the way in (CONTRACTS.md). The
composited channels are Glimpse's (colour, ones, depth, group indicators), so the
outputs mean the same as the other backends'.
"""

from __future__ import annotations

import torch
from torch import Tensor

from glimpse.errors import GlimpseError
from glimpse.render.projection import LOW_PASS, Camera, Projected

GSPLAT_PIXEL_OFFSET = 0.5


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
