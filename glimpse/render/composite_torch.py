"""Pure-PyTorch alpha compositing: the reference every faster backend is tested against,
and the fallback where no C++ compiler exists (autograd provides the backward).

Rules (shared with the C++ kernel): at pixel p, Gaussian i has
power = -0.5 (a dx² + c dy²) - b dx dy with (dx, dy) = mean - p; it is skipped when
power > 0 or alpha = min(0.999, o exp(power)) < 1/255; front to back, each kept
Gaussian adds alpha T f to the pixel and multiplies T by (1 - alpha), unless that
would bring T to 1e-4 or below: then the pixel stops.
"""

from __future__ import annotations

import torch
from torch import Tensor

from glimpse.render.binning import TileBins
from glimpse.render.projection import ALPHA_MAX, ALPHA_MIN, TRANSMITTANCE_MIN


def _composite_pixels(pixels: Tensor, means2d: Tensor, conics: Tensor, opacities: Tensor,
                      features: Tensor) -> Tensor:
    """pixels [P, 2] against Gaussians already in front-to-back order -> [P, C]."""
    d = means2d[None, :, :] - pixels[:, None, :]  # [P, n, 2]
    a, b, c = conics.unbind(-1)
    power = -0.5 * (a * d[..., 0] ** 2 + c * d[..., 1] ** 2) - b * d[..., 0] * d[..., 1]
    alpha = torch.clamp(opacities * torch.exp(power), max=ALPHA_MAX)
    alpha = torch.where((power <= 0) & (alpha >= ALPHA_MIN), alpha, torch.zeros_like(alpha))
    after = torch.cumprod(1.0 - alpha, dim=1)  # transmittance after each Gaussian, all kept
    kept = after > TRANSMITTANCE_MIN  # T only decreases: a prefix of the list
    before = torch.cat([torch.ones_like(after[:, :1]), after[:, :-1]], dim=1)
    weights = torch.where(kept, alpha * before, torch.zeros_like(alpha))
    return weights @ features


def _pixel_grid(x0: int, y0: int, x1: int, y1: int, like: Tensor) -> Tensor:
    ys, xs = torch.meshgrid(torch.arange(y0, y1), torch.arange(x0, x1), indexing="ij")
    return torch.stack([xs.reshape(-1), ys.reshape(-1)], -1).to(like)


def composite_torch(means2d: Tensor, conics: Tensor, opacities: Tensor, features: Tensor, bins: TileBins,
                    width: int, height: int) -> Tensor:
    """Tile by tile: features [N, C] -> image [H, W, C] (no background)."""
    channels = features.shape[1]
    rows = []
    for ty in range(bins.tiles_y):
        y0, y1 = ty * bins.tile_size, min((ty + 1) * bins.tile_size, height)
        row = []
        for tx in range(bins.tiles_x):
            x0, x1 = tx * bins.tile_size, min((tx + 1) * bins.tile_size, width)
            k = ty * bins.tiles_x + tx
            ids = bins.gaussian_ids[bins.tile_offsets[k]: bins.tile_offsets[k + 1]].long()
            if len(ids) == 0:
                tile = features.new_zeros((y1 - y0) * (x1 - x0), channels)
            else:
                tile = _composite_pixels(_pixel_grid(x0, y0, x1, y1, means2d), means2d[ids], conics[ids],
                                         opacities[ids], features[ids])
            row.append(tile.reshape(y1 - y0, x1 - x0, channels))
        rows.append(torch.cat(row, dim=1))
    return torch.cat(rows, dim=0)


def composite_dense(means2d: Tensor, conics: Tensor, opacities: Tensor, features: Tensor, depths: Tensor,
                    visible: Tensor, width: int, height: int) -> Tensor:
    """Every pixel against every visible Gaussian in depth order, no tiles: the test oracle for
    binning (memory grows as pixels x Gaussians: small scenes only). Returns [H, W, C]."""
    ids = torch.nonzero(visible).squeeze(1)
    ids = ids[torch.argsort(depths[ids], stable=True)]
    out = _composite_pixels(_pixel_grid(0, 0, width, height, means2d), means2d[ids], conics[ids],
                            opacities[ids], features[ids])
    return out.reshape(height, width, features.shape[1])
