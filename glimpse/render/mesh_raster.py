"""A z-buffer triangle rasterizer on the CPU (numpy): which triangle is nearest at each pixel,
and at what depth. Used to tell whose body covers a pixel (stage 03); not differentiable.

Conventions: OpenCV pinhole camera, points already in camera coordinates (x right, y down,
z forward, metres or world units); pixel (u, v) is covered when its centre, at (u, v) in K's
convention, lies inside the projected triangle or on its edge. Depth is the camera z of the
surface at the pixel centre (perspective-correct: 1/z interpolated linearly on the image).
Triangles with a corner nearer than ``near`` are dropped (no clipping).

The z-buffer runs in the C++ kernel (csrc/mesh_raster_cpu.cpp) where it builds, else in numpy, which
is the reference: both give the same arrays to the bit. In numpy every triangle is tested against the
pixels of its bounding box at once; triangles are grouped by bounding-box size (powers of two) so that
small ones, almost all of a body mesh, cost a few candidate pixels each.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NEAR = 1e-3  # camera z below which a triangle is dropped
MAX_CANDIDATES = 4_000_000  # candidate (triangle, pixel) pairs evaluated per chunk
MIN_AREA = 1e-12  # twice the projected area (pixels^2) below which a triangle covers nothing (csrc: kMinArea)


@dataclass(frozen=True)
class MeshRaster:
    """depth [H, W] float64 camera z of the nearest surface (inf where none); face [H, W] int64 index
    of that triangle (-1 where none)."""

    depth: np.ndarray
    face: np.ndarray


def rasterize_triangles(points: np.ndarray, faces: np.ndarray, K: np.ndarray, width: int, height: int,
                        near: float = NEAR, use_kernel: bool | None = None) -> MeshRaster:
    """points [V, 3] camera coordinates; faces [F, 3] vertex indices; K [3, 3] -> MeshRaster. ``use_kernel``:
    the C++ z-buffer (None: where it builds) or numpy (False); the same result either way."""
    points, faces = np.asarray(points, np.float64), np.asarray(faces, np.int64)
    if use_kernel is None:
        use_kernel = _kernel_available()
    if use_kernel:
        import torch

        from glimpse.render.composite_cpu import extension

        depth, face = extension().mesh_raster(torch.from_numpy(np.ascontiguousarray(points)),
                                              torch.from_numpy(np.ascontiguousarray(faces)), float(K[0, 0]),
                                              float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), near, width, height)
        return MeshRaster(depth.numpy(), face.numpy())
    return _rasterize_numpy(points, faces, K, width, height, near)


def _kernel_available() -> bool:
    """Whether the C++ kernels load (they are built once per environment, whatever ``render.backend`` says: this
    is not the Gaussian rasterizer); while another process builds them, numpy serves instead of waiting."""
    from glimpse.locks import LockBusy
    from glimpse.render.composite_cpu import available

    try:
        return available()
    except LockBusy:
        return False


def _rasterize_numpy(points: np.ndarray, faces: np.ndarray, K: np.ndarray, width: int, height: int, near: float
                     ) -> MeshRaster:
    """The reference z-buffer (``rasterize_triangles``'s arguments)."""
    corners = points[faces]  # [F, 3, 3]
    ids = np.nonzero((corners[:, :, 2] > near).all(1))[0]
    corners = corners[ids]
    uv = corners[:, :, :2] / corners[:, :, 2:3] * [K[0, 0], K[1, 1]] + K[:2, 2]  # [F, 3, 2]
    low = np.maximum(np.ceil(uv.min(1)), 0).astype(np.int64)  # [F, 2] first pixel centre inside the box
    high = np.minimum(np.floor(uv.max(1)), [width - 1, height - 1]).astype(np.int64)
    extent = (high - low + 1).max(1)  # [F] box side in pixels (<= 0: misses every pixel centre)
    pixel_parts, depth_parts, face_parts = [], [], []
    side = 1
    while True:
        group = np.nonzero((extent > side // 2) & (extent <= side))[0] if side > 1 else np.nonzero(extent == 1)[0]
        chunk = max(1, MAX_CANDIDATES // (side * side))
        for start in range(0, len(group), chunk):
            rows = group[start:start + chunk]
            hit = _cover(uv[rows], 1.0 / corners[rows, :, 2], low[rows], high[rows], side)
            if hit is not None:
                row, u, v, depth = hit
                pixel_parts.append(v * width + u)
                depth_parts.append(depth)
                face_parts.append(ids[rows[row]])
        if side >= max(width, height) or not (extent > side).any():
            break
        side *= 2
    depth_map = np.full(height * width, np.inf)
    face_map = np.full(height * width, -1, np.int64)
    if pixel_parts:
        pixel, depth, face = np.concatenate(pixel_parts), np.concatenate(depth_parts), np.concatenate(face_parts)
        order = np.lexsort((face, depth, pixel))  # per pixel: nearest first (ties: lower face id)
        first = order[np.unique(pixel[order], return_index=True)[1]]
        depth_map[pixel[first]], face_map[pixel[first]] = depth[first], face[first]
    return MeshRaster(depth_map.reshape(height, width), face_map.reshape(height, width))


def rasterize_meshes(meshes: list[np.ndarray], faces: np.ndarray, K: np.ndarray, width: int, height: int
                     ) -> MeshRaster:
    """Several meshes of one topology (each [V, 3], camera coordinates; faces [F, 3]) in one z-buffer; the face
    index of mesh k's triangle f is ``k * F + f``, so ``face // F`` says whose surface is nearest."""
    return rasterize_triangles(np.concatenate(meshes),
                               np.concatenate([faces + k * len(meshes[0]) for k in range(len(meshes))]),
                               K, width, height)


def _cover(uv: np.ndarray, inv_z: np.ndarray, low: np.ndarray, high: np.ndarray, side: int):
    """Pixels of each triangle's box (side x side from ``low``, clipped at ``high``) inside it:
    (triangle row, u, v, depth) arrays, or None. uv [N, 3, 2]; inv_z [N, 3] = 1 / z of the corners."""
    offsets = np.arange(side)
    u = low[:, 0, None, None] + offsets[None, None, :]  # [N, 1, S]
    v = low[:, 1, None, None] + offsets[None, :, None]  # [N, S, 1]
    in_box = (u <= high[:, 0, None, None]) & (v <= high[:, 1, None, None])  # [N, S, S]
    a, b, c = uv[:, 0], uv[:, 1], uv[:, 2]  # [N, 2]
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])  # [N]
    usable = np.abs(area) > MIN_AREA
    sign = np.where(area < 0, -1.0, 1.0)[:, None, None]

    def edge(p: np.ndarray, q: np.ndarray) -> np.ndarray:  # twice the signed area of (p, q, pixel)
        return ((q[:, 0] - p[:, 0])[:, None, None] * (v - p[:, 1, None, None])
                - (q[:, 1] - p[:, 1])[:, None, None] * (u - p[:, 0, None, None]))

    w_a, w_b, w_c = sign * edge(b, c), sign * edge(c, a), sign * edge(a, b)  # barycentric x |area|
    inside = in_box & (w_a >= 0) & (w_b >= 0) & (w_c >= 0) & usable[:, None, None]
    row, j, i = np.nonzero(inside)
    if len(row) == 0:
        return None
    weights = np.stack([w_a[row, j, i], w_b[row, j, i], w_c[row, j, i]], 1) / np.abs(area[row])[:, None]
    depth = 1.0 / (weights * inv_z[row]).sum(1)
    return row, u[row, 0, i], v[row, j, 0], depth
