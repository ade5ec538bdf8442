"""Whose body is nearest at each pixel of one frame: every posed body mesh rasterized together
(glimpse.render.mesh_raster), plus each body's own full projection (as if nothing hid it)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from glimpse.cameras.model import PinholeCamera
from glimpse.render.mesh_raster import rasterize_meshes, rasterize_triangles


@dataclass(frozen=True)
class BodyLayers:
    """owner [H, W] index (into the bodies given) of the nearest body, -1 where none; faces [N, H, W]
    each body's own nearest triangle at each pixel (its whole projection, as if nothing hid it; -1
    where none); pelvis_depth [N] camera z of each pelvis (world units)."""

    owner: np.ndarray
    faces: np.ndarray
    pelvis_depth: np.ndarray

    @property
    def full(self) -> np.ndarray:
        """[N, H, W] bool each body's whole projection."""
        return self.faces >= 0


def body_layers(vertices: list[np.ndarray], pelvis: list[np.ndarray], faces: np.ndarray, camera: PinholeCamera,
                width: int, height: int) -> BodyLayers:
    """vertices: per body [V, 3] world; pelvis: per body [3] world; faces [F, 3] shared topology."""
    count = len(vertices)
    if count == 0:
        return BodyLayers(np.full((height, width), -1, np.int64), np.zeros((0, height, width), np.int64), np.zeros(0))
    cam = [v @ camera.R.T + camera.t for v in vertices]
    own = np.stack([rasterize_triangles(c, faces, camera.K, width, height).face for c in cam])
    together = rasterize_meshes(cam, faces, camera.K, width, height)
    owner = np.where(together.face >= 0, together.face // len(faces), -1)
    depth = np.array([(p @ camera.R.T + camera.t)[2] for p in pelvis])
    return BodyLayers(owner, own, depth)
