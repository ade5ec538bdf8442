"""Tile binning: which Gaussians touch which 16x16 tile, sorted front to back."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor


@dataclass(frozen=True)
class TileBins:
    """gaussian_ids [M] int32: Gaussians of tile 0 front to back, then tile 1, ...;
    tile_offsets [tiles_y * tiles_x + 1] int32: tile k's entries are
    gaussian_ids[tile_offsets[k]:tile_offsets[k + 1]] (tiles in row-major order)."""

    gaussian_ids: Tensor
    tile_offsets: Tensor
    tile_size: int
    tiles_x: int
    tiles_y: int


@torch.no_grad()
def bin_gaussians(means2d: Tensor, extents: Tensor, depths: Tensor, visible: Tensor, width: int, height: int,
                  tile_size: int, use_cpu_kernel: bool = False) -> TileBins:
    """Assign each visible Gaussian to every tile its box (mean +- extents, pixels) overlaps.

    Within a tile, Gaussians are ordered by depth, ties by index. ``use_cpu_kernel``: the C++
    kernel (a radix sort by depth, then a counting sort into tiles: same result, faster); otherwise one sort
    on (tile, depth rank) keys.
    """
    tiles_x, tiles_y = -(-width // tile_size), -(-height // tile_size)
    if use_cpu_kernel:
        from glimpse.render.composite_cpu import extension

        inputs = [t.detach().float().contiguous() for t in (means2d, extents, depths)]
        gaussian_ids, offsets = extension().bin_gaussians(*inputs, visible.contiguous(), width, height, tile_size)
        return TileBins(gaussian_ids, offsets, tile_size, tiles_x, tiles_y)
    ids = torch.nonzero(visible).squeeze(1)
    ids = ids[torch.argsort(depths[ids], stable=True)]  # front to back, ties by index
    lo = torch.floor((means2d[ids] - extents[ids]) / tile_size).to(torch.int64)
    hi = torch.floor((means2d[ids] + extents[ids]) / tile_size).to(torch.int64)
    x0, y0 = lo[:, 0].clamp(0, tiles_x - 1), lo[:, 1].clamp(0, tiles_y - 1)
    x1, y1 = hi[:, 0].clamp(0, tiles_x - 1), hi[:, 1].clamp(0, tiles_y - 1)
    counts_x, counts_y = x1 - x0 + 1, y1 - y0 + 1
    counts = counts_x * counts_y
    owner = torch.repeat_interleave(torch.arange(len(ids)), counts)  # [M] index into ids
    first = torch.cumsum(counts, 0) - counts
    local = torch.arange(len(owner)) - first[owner]  # position within the Gaussian's tile rectangle
    tile_x = x0[owner] + local % counts_x[owner]
    tile_y = y0[owner] + local // counts_x[owner]
    tile = tile_y * tiles_x + tile_x
    order = torch.argsort(tile * len(ids) + owner)  # ids are in depth order: owner is the depth rank
    gaussian_ids = ids[owner[order]].to(torch.int32)
    offsets = torch.zeros(tiles_x * tiles_y + 1, dtype=torch.int64)
    offsets[1:] = torch.cumsum(torch.bincount(tile, minlength=tiles_x * tiles_y), 0)
    return TileBins(gaussian_ids, offsets.to(torch.int32), tile_size, tiles_x, tiles_y)
