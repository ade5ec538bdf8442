"""Vertex normals of a triangle mesh (numpy), shared by the overlay, the visibility record and the fixtures."""

from __future__ import annotations

import numpy as np


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """[V, 3] unit area-weighted vertex normals of a mesh (vertices [V, 3], faces [F, 3] counter-clockwise seen
    from outside); zero for a vertex no face touches. Each vertex sums its faces' normals in float64, in face order,
    corner 0's faces first: for float64 vertices the values ``np.add.at`` corner by corner gives, here by one
    ``np.bincount`` per axis (float32 vertices are summed more exactly than add.at would)."""
    corners = vertices[faces]
    face_normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])  # length = 2 x area
    corner_vertex = faces.T.reshape(-1)  # corner 0 of every face, then corner 1, then corner 2
    per_corner = np.tile(face_normals, (3, 1))
    normals = np.stack([np.bincount(corner_vertex, per_corner[:, axis], minlength=len(vertices))
                        for axis in range(3)], axis=1).astype(vertices.dtype, copy=False)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)
