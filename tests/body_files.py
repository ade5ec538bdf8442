"""Random SMPL-format model files for tests and benchmarks (no real SMPL data needed).

The model is random but sane: a 1.7 m blob of 6,890 vertices, small shape and pose
bases, convex joint regressor rows, skinning weight rows summing to 1, SMPL's
kinematic tree and random valid faces. Every float is exactly representable in
float32, so references that cast the file to float32 on load (smplx, body_models)
see the very same model as a float64 reader.

``write_random_smpl_pkl(..., chumpy_style=True)`` writes the official layout: arrays
wrapped in fake ``chumpy`` objects and a ``scipy.sparse`` J_regressor. The fake
``chumpy`` modules exist in ``sys.modules`` only while pickling, so a reader must
use its own chumpy shim.
"""

from __future__ import annotations

import pickle
import sys
import types
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse

SMPL_NUM_VERTICES = 6890
NUM_JOINTS = 24
NUM_POSE_FEATURES = 207
SMPL_KINTREE_PARENTS = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21)
ROOT_PARENT_UINT32 = 4294967295  # how the official files store the root's parent
BODY_HEIGHT_M = 1.7
BODY_HALF_WIDTH_M = 0.25
BODY_HALF_DEPTH_M = 0.12
SHAPE_STD_M = 0.01  # vertex offset per unit beta
POSE_STD_M = 0.005  # vertex offset per unit pose feature
REGRESSOR_VERTICES_PER_JOINT = 8
MAX_JOINTS_PER_VERTEX = 4
WEIGHT_QUANTUM = 2.0**-20  # convex weights on this grid sum exactly to 1 in float32 and float64
PYTHON2_PICKLE_PROTOCOL = 2  # the official files were written by Python 2's cPickle, protocol 2


def _f32(array: np.ndarray) -> np.ndarray:
    """float64 values that are exactly representable in float32."""
    return np.asarray(array, dtype=np.float32).astype(np.float64)


def _convex_rows(rng: np.random.Generator, rows: int, cols: int, active: list[np.ndarray]) -> np.ndarray:
    """[rows, cols] nonnegative, each row's nonzeros at active[r] (its columns), rows summing exactly to 1.

    Values are multiples of WEIGHT_QUANTUM (exact in float32, and so are their sums).
    """
    out = np.zeros((rows, cols))
    for r, columns in enumerate(active):
        values = np.floor(rng.dirichlet(np.ones(len(columns))) / WEIGHT_QUANTUM) * WEIGHT_QUANTUM
        values[-1] = 1.0 - values[:-1].sum()
        out[r, columns] = values
    return out


def random_smpl_arrays(
    seed: int, num_vertices: int = SMPL_NUM_VERTICES, num_shape: int = 10, num_faces: int | None = None
) -> dict[str, np.ndarray]:
    """The arrays of a random SMPL-format model (keys as in the official files)."""
    rng = np.random.default_rng(seed)
    # rest-pose blob: an ellipsoid 1.7 m tall (y up, facing +z), feet near y = -0.85 m
    direction = rng.normal(size=(num_vertices, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    radius = rng.uniform(0.0, 1.0, size=(num_vertices, 1)) ** (1.0 / 3.0)
    half_extent = np.array([BODY_HALF_WIDTH_M, BODY_HEIGHT_M / 2.0, BODY_HALF_DEPTH_M])
    v_template = _f32(direction * radius * half_extent)
    shapedirs = _f32(rng.normal(scale=SHAPE_STD_M, size=(num_vertices, 3, num_shape)))
    posedirs = _f32(rng.normal(scale=POSE_STD_M, size=(num_vertices, 3, NUM_POSE_FEATURES)))

    per_joint = min(REGRESSOR_VERTICES_PER_JOINT, num_vertices)
    regressor_support = [rng.choice(num_vertices, size=per_joint, replace=False) for _ in range(NUM_JOINTS)]
    J_regressor = _convex_rows(rng, NUM_JOINTS, num_vertices, regressor_support)
    joints = J_regressor @ v_template
    nearest = np.argmin(np.linalg.norm(v_template[:, None] - joints[None], axis=2), axis=1)
    weight_support = []
    for v in range(num_vertices):
        others = rng.choice(NUM_JOINTS, size=rng.integers(0, MAX_JOINTS_PER_VERTEX), replace=False)
        weight_support.append(np.unique(np.concatenate([[nearest[v]], others])))
    weights = _convex_rows(rng, num_vertices, NUM_JOINTS, weight_support)

    kintree = np.array([SMPL_KINTREE_PARENTS, range(NUM_JOINTS)], dtype=np.int64)
    kintree[0, 0] = ROOT_PARENT_UINT32
    faces = rng.integers(0, num_vertices, size=(num_faces or 2 * num_vertices - 4, 3)).astype(np.uint32)
    return {
        "v_template": v_template,
        "shapedirs": shapedirs,
        "posedirs": posedirs,
        "J_regressor": J_regressor,
        "weights": weights,
        "kintree_table": kintree,
        "f": faces,
    }


# --------------------------------------------------------------------------- fake chumpy


class FakeCh:
    """Pickles like chumpy's ``Ch``: its __dict__ minus weak dictionaries, dense value under 'x'."""

    def __init__(self, x: np.ndarray):
        self.x = np.asarray(x, dtype=np.float64)
        self._dirty_vars: set[str] = set()
        self._itr = None
        self._make_dense = False
        self._make_sparse = False
        self._depends_on_deps: dict[str, Any] = {}

    def __getstate__(self) -> dict[str, Any]:
        return dict(self.__dict__)


class FakeSelect(FakeCh):
    """Pickles like chumpy's ``reordering.Select``: a source Ch 'a' read at flat indices 'idxs'."""

    def __init__(self, value: np.ndarray):
        value = np.asarray(value, dtype=np.float64)
        self.a = FakeCh(value.reshape(-1))
        self.idxs = np.arange(value.size)
        self.preferred_shape = value.shape
        self._dirty_vars = set()
        self._itr = None
        self._depends_on_deps = {}


FakeCh.__module__, FakeCh.__qualname__, FakeCh.__name__ = "chumpy.ch", "Ch", "Ch"
FakeSelect.__module__, FakeSelect.__qualname__, FakeSelect.__name__ = "chumpy.reordering", "Select", "Select"
_FAKE_MODULES = {"chumpy": {}, "chumpy.ch": {"Ch": FakeCh}, "chumpy.reordering": {"Select": FakeSelect}}


def _dump_with_fake_chumpy(obj: Any, path: Path, protocol: int) -> None:
    """Pickle obj while fake chumpy modules are importable; remove them afterwards."""
    if any(name in sys.modules for name in _FAKE_MODULES):
        raise RuntimeError("a chumpy module is already imported; the fake one would shadow it")
    try:
        for name, members in _FAKE_MODULES.items():
            module = types.ModuleType(name)
            module.__dict__.update(members)
            sys.modules[name] = module
        with open(path, "wb") as handle:
            pickle.dump(obj, handle, protocol=protocol)
    finally:
        for name in _FAKE_MODULES:
            sys.modules.pop(name, None)


# --------------------------------------------------------------------------- writers


def write_random_smpl_pkl(
    path: str | Path,
    seed: int,
    chumpy_style: bool,
    *,
    num_vertices: int = SMPL_NUM_VERTICES,
    protocol: int = PYTHON2_PICKLE_PROTOCOL,
) -> Path:
    """Write a random SMPL model as a pickled dict.

    chumpy_style=False: plain numpy arrays (dense J_regressor), readable by smplx.
    chumpy_style=True: the official layout: v_template, posedirs, weights and J as
    fake ``chumpy.ch.Ch``, shapedirs as a fake ``chumpy.reordering.Select``,
    J_regressor (and J_regressor_prior) as ``scipy.sparse.csc_matrix``, plus the
    official files' other entries (strings, a dict, priors).
    """
    path = Path(path)
    arrays = random_smpl_arrays(seed, num_vertices=num_vertices)
    if not chumpy_style:
        with open(path, "wb") as handle:
            pickle.dump(arrays, handle, protocol=protocol)
        return path
    official: dict[str, Any] = {
        "v_template": FakeCh(arrays["v_template"]),
        "shapedirs": FakeSelect(arrays["shapedirs"]),
        "posedirs": FakeCh(arrays["posedirs"]),
        "weights": FakeCh(arrays["weights"]),
        "J_regressor": scipy.sparse.csc_matrix(arrays["J_regressor"]),
        "kintree_table": arrays["kintree_table"],
        "f": arrays["f"],
        "J": FakeCh(arrays["J_regressor"] @ arrays["v_template"]),
        "J_regressor_prior": scipy.sparse.csc_matrix(arrays["J_regressor"]),
        "weights_prior": arrays["weights"].copy(),
        "vert_sym_idxs": np.arange(num_vertices, dtype=np.int64),
        "bs_style": "lbs",
        "bs_type": "lrotmin",
        "pose_training_info": {"num_subjects": 1, "ds_name": "random"},
    }
    _dump_with_fake_chumpy(official, path, protocol)
    return path


def write_random_smpl_npz(path: str | Path, seed: int, **entries: Any) -> Path:
    """Write a random SMPL model as an .npz (keys as in the pkl).

    entries add or replace keys (e.g. ``body_model="free"``, ``format="glimpse-body/1"``,
    extra arrays); an entry set to None removes that key. Keyword ``num_vertices`` /
    ``num_shape`` size the model (defaults 6,890 and 10).
    """
    path = Path(path)
    num_vertices = entries.pop("num_vertices", SMPL_NUM_VERTICES)
    num_shape = entries.pop("num_shape", 10)
    arrays: dict[str, Any] = dict(random_smpl_arrays(seed, num_vertices=num_vertices, num_shape=num_shape))
    for key, value in entries.items():
        if value is None:
            arrays.pop(key, None)
        else:
            arrays[key] = np.asarray(value)
    np.savez(path, **arrays)
    return path
