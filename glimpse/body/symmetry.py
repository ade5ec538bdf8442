"""The body's left-right mirror and its surface graph, from the template mesh alone.

The template (rest pose, mean shape) is close to symmetric about its sagittal plane x = 0 (SMPL
axes: x to the body's left, y up, z forward), so each vertex's mirror is the vertex nearest to its
reflection. Used by the surface prior to carry what one side of a person showed to the other.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def mirror_vertex_map(template: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """template [V, 3] rest-pose vertices -> (mirror [V] int: the vertex nearest each vertex's reflection
    across x = 0, distance [V]: how far that vertex is from the reflection, template units)."""
    reflected = template * np.array([-1.0, 1.0, 1.0])
    distance, mirror = cKDTree(template).query(reflected)
    return mirror.astype(np.int64), distance


def mesh_edges(faces: np.ndarray) -> np.ndarray:
    """[E, 2] every undirected edge of a triangle mesh once (smaller index first)."""
    pairs = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return np.unique(np.sort(pairs, axis=1), axis=0)
