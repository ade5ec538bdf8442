"""Completing a per-vertex quantity over the body surface from the vertices where it is known.

The body graph is the mesh's edges plus an edge from each vertex to its left-right mirror
(glimpse.body.symmetry), weighted ``mirror_weight`` against 1 for a mesh edge. Unknown values
minimise the graph's Dirichlet energy plus a pull of weight ``anchor_weight`` towards an anchor
value per vertex (screened harmonic extension): an unknown vertex takes the weighted mean of its
neighbours and its anchor, so a colour seen on one side crosses to the mirror side and spreads
along the surface, while far from anything seen it settles on its anchor (the seen mean of its
body part, or of the nearest ancestor part the views saw, :func:`part_means`).
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix, identity
from scipy.sparse.linalg import spsolve

MIN_ANCHOR = 1e-6  # smallest pull towards the anchors (keeps vertices cut off from every known one defined)


def body_graph(edges: np.ndarray, mirror: np.ndarray, mirror_weight: float, vertex_count: int) -> coo_matrix:
    """Symmetric weighted adjacency [V, V] of the mesh edges [E, 2] (weight 1) and the mirror pairs."""
    own = mirror != np.arange(vertex_count)
    rows = np.concatenate([edges[:, 0], edges[:, 1], np.arange(vertex_count)[own]])
    cols = np.concatenate([edges[:, 1], edges[:, 0], mirror[own]])
    weights = np.concatenate([np.ones(2 * len(edges)), np.full(int(own.sum()), mirror_weight)])
    return coo_matrix((weights, (rows, cols)), shape=(vertex_count, vertex_count)).tocsr()


def part_groups(labels: np.ndarray, mirror: np.ndarray) -> np.ndarray:
    """[V] one group per body part and its mirror image (the left and right arm share one), from per-vertex
    part labels [V] and the mirror map [V]."""
    return np.minimum(labels, labels[mirror])


def part_parents(labels: np.ndarray, groups: np.ndarray, joint_parents: np.ndarray) -> np.ndarray:
    """[J] for each group (named by its joint index, :func:`part_groups`) the group of its parent part:
    the groups of the vertices labelled with the nearest ancestor joint that labels any (the most common
    one); -1 for the root. labels [V] joint per vertex, joint_parents [J] (-1 for the root)."""
    parent_group = np.full(len(joint_parents), -1)
    for group in np.unique(groups):
        parent = int(joint_parents[group])
        while parent >= 0:
            members = groups[labels == parent]
            if len(members):
                parent_group[group] = int(np.bincount(members).argmax())
                break
            parent = int(joint_parents[parent])
    return parent_group


def part_means(values: np.ndarray, known: np.ndarray, groups: np.ndarray,
               parent_group: np.ndarray | None = None, min_share: float = 0.0) -> np.ndarray:
    """[V, C]: at each vertex, the mean of ``values [V, C]`` over the known vertices of its group, if at least
    ``min_share`` of the group's vertices are known (a few stray vertices are not a part's colour); else that
    of its nearest ancestor group that qualifies (``parent_group``, :func:`part_parents`: unseen shins take the
    thighs' colour), else the mean over every known vertex (zeros when nothing is known)."""
    overall = values[known].mean(axis=0) if known.any() else np.zeros(values.shape[1])
    means = {}
    for group in np.unique(groups[known]):
        members = groups == group
        if (members & known).sum() >= min_share * members.sum():
            means[int(group)] = values[members & known].mean(axis=0)
    anchors = np.tile(overall, (len(values), 1))
    for group in np.unique(groups):
        source = int(group)
        for _ in range(len(parent_group) if parent_group is not None else 0):
            if source in means or source < 0:
                break
            source = int(parent_group[source])
        if source in means:
            anchors[groups == group] = means[source]
    return anchors


def harmonic_fill(values: np.ndarray, known: np.ndarray, graph, anchors: np.ndarray | None = None,
                  anchor_weight: float = 0.0) -> np.ndarray:
    """values [V, C] (read where ``known [V]`` is True) -> [V, C] with the unknown rows replaced by the
    screened harmonic extension on ``graph`` [V, V] (body_graph), pulled towards ``anchors [V, C]`` (default:
    the known mean) with ``anchor_weight``. With nothing known the values come back unchanged."""
    if known.all() or not known.any():
        return values.copy()
    unknown = ~known
    degree = np.asarray(graph.sum(axis=1)).ravel()
    laplacian = (coo_matrix((degree, (np.arange(len(degree)), np.arange(len(degree)))), shape=graph.shape)
                 - graph).tocsr()
    if anchors is None:
        anchors = np.tile(values[known].mean(axis=0), (len(values), 1))
    pull = max(anchor_weight, MIN_ANCHOR)
    system = laplacian[unknown][:, unknown] + pull * identity(int(unknown.sum()), format="csr")
    right = -(laplacian[unknown][:, known] @ values[known]) + pull * anchors[unknown]
    filled = values.copy()
    solution = spsolve(system.tocsc(), right)
    filled[unknown] = solution.reshape(int(unknown.sum()), -1)
    return filled
