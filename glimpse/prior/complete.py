"""Completing a per-vertex quantity over the body surface from the vertices where it is known.

The body graph is the mesh's edges plus an edge from each vertex to its left-right mirror
(glimpse.body.symmetry), weighted ``mirror_weight`` against 1 for a mesh edge. The completed values
minimise the graph's Dirichlet energy plus, at each vertex with data, its confidence times the
squared distance to its data, and at each vertex without, a pull of weight ``anchor_weight``
towards an anchor value (a screened Poisson problem, :func:`screened_fill`): an unknown vertex
takes the weighted mean of its neighbours and its anchor, so a colour seen on one side crosses to
the mirror side and spreads along the surface, while far from anything seen it settles on its
anchor (the seen mean of its body part, or of the nearest ancestor part the views saw,
:func:`part_means`). Data held by little opacity (a few faint Gaussians) yields to its neighbours.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix, diags
from scipy.sparse.linalg import spsolve

MIN_ANCHOR = 1e-6  # smallest pull towards the anchors (keeps vertices cut off from every known one defined)
CG_RTOL = 1e-10  # conjugate gradients stop at this residual, relative to the right-hand side
CG_MAX_ITERATIONS = 2000  # beyond this many steps a column is solved directly


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
               parent_group: np.ndarray | None = None, min_share: float = 0.0,
               weights: np.ndarray | None = None) -> np.ndarray:
    """[V, C]: at each vertex, the mean of ``values [V, C]`` over the known vertices of its group (weighted by
    ``weights [V]``, default equal), if at least ``min_share`` of the group's vertices are known (a few stray
    vertices are not a part's colour); else that of its nearest ancestor group that qualifies (``parent_group``,
    :func:`part_parents`: unseen shins take the thighs' colour), else the mean over every known vertex (zeros
    when nothing is known)."""
    weights = np.ones(len(values)) if weights is None else np.asarray(weights, np.float64)

    def mean(rows: np.ndarray) -> np.ndarray:
        total = weights[rows].sum()
        return (values[rows] * weights[rows, None]).sum(0) / total if total > 0 else values[rows].mean(axis=0)

    overall = mean(known) if known.any() else np.zeros(values.shape[1])
    means = {}
    for group in np.unique(groups[known]):
        members = groups == group
        if (members & known).sum() >= min_share * members.sum():
            means[int(group)] = mean(members & known)
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


def screened_fill(values: np.ndarray, confidence: np.ndarray, graph, anchors: np.ndarray | None = None,
                  anchor_weight: float = 0.0, initial: np.ndarray | None = None) -> np.ndarray:
    """values [V, C] (read where ``confidence [V]`` > 0) -> [V, C] minimising, over every vertex not held
    exactly (``confidence`` inf), the graph's Dirichlet energy on ``graph`` [V, V] (body_graph) plus
    ``confidence x (x - value)^2`` at the vertices with data and ``anchor_weight x (x - anchor)^2`` at those
    without (``anchors [V, C]``, default: the mean of the data, a held vertex weighing 1 and the others their
    confidence). A vertex whose data is
    weak (little opacity behind its colour) is smoothed by its neighbours; with infinite confidence this is
    the screened harmonic extension from the known vertices. With no data the values come back unchanged.
    ``initial [V, C]``: where the solver starts (an earlier fill of nearly the same data: fewer steps)."""
    held = np.isinf(confidence)
    has_data = held | (confidence > 0)
    if held.all() or not has_data.any():
        return values.copy()
    degree = np.asarray(graph.sum(axis=1)).ravel()
    laplacian = (coo_matrix((degree, (np.arange(len(degree)), np.arange(len(degree)))), shape=graph.shape)
                 - graph).tocsr()
    if anchors is None:
        weight = np.where(held, 1.0, np.where(has_data, confidence, 0.0))
        anchors = np.tile((values * weight[:, None]).sum(0) / weight.sum(), (len(values), 1))
    free = ~held
    data = np.where(has_data, np.where(held, 0.0, confidence), 0.0)[free]
    pull = np.where(has_data[free], 0.0, max(anchor_weight, MIN_ANCHOR))
    right = data[:, None] * values[free] + pull[:, None] * anchors[free]
    if held.any():  # the held vertices enter as boundary values
        right = right - laplacian[free][:, held] @ values[held]
        laplacian = laplacian[free][:, free]
    system = laplacian + diags(data + pull, format="csr")
    filled = values.copy()
    start = None if initial is None else np.asarray(initial, np.float64)[free].reshape(int(free.sum()), -1)
    filled[free] = _solve(system.tocsr(), right.reshape(int(free.sum()), -1), start)
    return filled


def _solve(system, right: np.ndarray, initial: np.ndarray | None = None) -> np.ndarray:
    """system [n, n] (symmetric positive definite) x = right [n, C], from ``initial [n, C]`` (default zeros):
    conjugate gradients with a Jacobi preconditioner, every column at once (a few times faster than a direct
    solve on a body's graph), a direct solve for the columns they do not settle."""
    right = np.ascontiguousarray(right.T)  # [C, n]: one contiguous row per column, for the row-wise sums below

    def apply(rows: np.ndarray) -> np.ndarray:
        return np.stack([system @ row for row in rows])

    solution = np.zeros_like(right) if initial is None else np.array(initial.T, dtype=np.float64, order="C")
    residual = right - apply(solution)
    settled = CG_RTOL * np.sqrt((right * right).sum(1))
    inverse_diagonal = 1.0 / system.diagonal()
    preconditioned = inverse_diagonal * residual
    direction = preconditioned.copy()
    product = (residual * preconditioned).sum(1)
    for _ in range(CG_MAX_ITERATIONS):
        active = np.sqrt((residual * residual).sum(1)) > settled
        if not active.any():
            break
        image = apply(direction)
        curvature = (direction * image).sum(1)
        step = np.divide(product, curvature, out=np.zeros_like(product), where=active & (curvature > 0))
        solution += step[:, None] * direction
        residual -= step[:, None] * image
        preconditioned = inverse_diagonal * residual
        new_product = (residual * preconditioned).sum(1)
        ratio = np.divide(new_product, product, out=np.zeros_like(product), where=product > 0)
        direction = preconditioned + ratio[:, None] * direction
        product = new_product
    for column in np.flatnonzero(np.sqrt((residual * residual).sum(1)) > settled):
        solution[column] = spsolve(system.tocsc(), right[column])
    return solution.T
