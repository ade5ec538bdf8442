"""Reading SMPL-format body model files (official ``.pkl`` without chumpy, or ``.npz``).

Two layouts are read into one :class:`BodyModelData` (numpy, float64, read-only arrays):

1. the official pickles (``SMPL_NEUTRAL.pkl``, ``basicModel_*.pkl``): a dict, maybe
   written by Python 2, whose arrays are chumpy ``Ch`` objects and whose
   ``J_regressor`` is a ``scipy.sparse`` matrix. They load *without* chumpy: a
   restricted unpickler maps every ``chumpy.*`` class to a stand-in that keeps the
   pickled state (chumpy's ``Ch`` stores its dense value under ``'x'``; its
   ``reordering.Select`` stores a source ``'a'`` and flat indices ``'idxs'``) and
   refuses every class that is not numpy, scipy.sparse or chumpy (a pickle can run code);
2. ``.npz`` archives with the same keys, read with ``allow_pickle=False``. The
   project's free model is such an archive with ``body_model="free"``,
   ``format="glimpse-body/1"`` and extra arrays (kept in ``extras``).

Keys: ``v_template [V, 3]``, ``shapedirs [V, 3, S>=10]``, ``posedirs [V, 3, 207]`` or
``[V*3, 207]``, ``J_regressor [24, V]`` (dense or sparse), ``weights [V, 24]``,
``kintree_table [2, 24]`` (root parent -1 or 4294967295), ``f [F, 3]``.
Units: metres; rest (T) pose, y up, facing +z.
"""

from __future__ import annotations

import codecs
import copyreg
import pickle
import types
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse

from glimpse.errors import GlimpseError

NUM_JOINTS = 24
NUM_BODY_JOINTS = 23
JOINT_NAMES = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle",
    "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head",
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
    "left_hand", "right_hand",
)  # fmt: skip
SMPL_PARENTS = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21)
BODY_MODEL_FORMAT = "glimpse-body/1"

BODY_MODEL_KINDS = ("smpl", "free")
MIN_SHAPE_COMPONENTS = 10
NUM_POSE_FEATURES = 9 * NUM_BODY_JOINTS  # (R - I) of every non-root joint, flattened: 207
REQUIRED_KEYS = ("v_template", "shapedirs", "posedirs", "J_regressor", "weights", "kintree_table", "f")
METADATA_KEYS = ("body_model", "format")
# The root's parent in official files: -1, or -1 stored as an unsigned 32/64-bit integer.
ROOT_PARENT_CODES = (-1, 2**32 - 1, 2**64 - 1)
# Skinning weights of each vertex must sum to 1 (the transforms contract relies on it).
WEIGHT_SUM_TOLERANCE = 1e-3
ARRAY_KINDS = "biufcUS"  # numpy dtype kinds kept as arrays: bool, numbers, strings (not objects)


class BodyModelFileError(GlimpseError, ValueError):
    """A body model file (or in-memory model data) is unreadable or breaks the SMPL layout."""


class BodyModelNotFoundError(GlimpseError, FileNotFoundError):
    """The body model file does not exist."""


@dataclass(frozen=True)
class BodyModelData:
    """One SMPL-format body model as read-only numpy arrays (float64 / int64).

    Constructing it validates and normalises the arrays (raises BodyModelFileError).
    """

    kind: str  # "smpl" or "free": the file's "body_model" entry if present, else "smpl"
    v_template: np.ndarray  # [V, 3] float64, metres, rest (T) pose, y up, facing +z
    shapedirs: np.ndarray  # [V, 3, S] S >= 10, metres per unit beta
    posedirs: np.ndarray  # [V, 3, 207] pose correctives, metres per unit feature (zeros allowed)
    J_regressor: np.ndarray  # [24, V] dense float64
    weights: np.ndarray  # [V, 24] skinning weights, rows sum to 1
    parents: np.ndarray  # [24] int64, parents[0] == -1 (SMPL's tree)
    faces: np.ndarray  # [F, 3] int64 vertex indices
    extras: Mapping[str, np.ndarray] = field(default_factory=dict)  # every other array, read-only
    source: Path = Path("<memory>")

    def __post_init__(self) -> None:
        where = str(self.source)
        normalised = _validated_arrays(self, where)
        for name, value in normalised.items():
            object.__setattr__(self, name, value)
        extras = {str(k): _read_only(np.array(v, copy=True)) for k, v in dict(self.extras).items()}
        object.__setattr__(self, "extras", types.MappingProxyType(extras))
        object.__setattr__(self, "source", Path(self.source))

    @property
    def num_vertices(self) -> int:
        return int(self.v_template.shape[0])

    @property
    def num_shape_components(self) -> int:
        return int(self.shapedirs.shape[2])


def load_body_model_file(path: str | Path) -> BodyModelData:
    """Read an SMPL-format ``.pkl`` (official, chumpy-free) or ``.npz`` model file.

    Raises BodyModelNotFoundError (a FileNotFoundError) when the file is missing and
    BodyModelFileError (a ValueError) naming the file and the problem otherwise.
    """
    path = Path(path)
    if not path.is_file():
        raise BodyModelNotFoundError(f"body model file not found: {path} (give the path of a .pkl or .npz model)")
    suffix = path.suffix.lower()
    if suffix == ".pkl":
        entries = _read_pickle(path)
    elif suffix == ".npz":
        entries = _read_npz(path)
    else:
        raise BodyModelFileError(f"{path}: unknown body model file type {path.suffix!r} (expected .pkl or .npz)")
    return _data_from_entries(entries, path)


# --------------------------------------------------------------------------- assembling


def _data_from_entries(entries: dict[str, Any], path: Path) -> BodyModelData:
    """Entries of a file (arrays, chumpy stand-ins, sparse matrices, strings) -> BodyModelData."""
    where = str(path)
    missing = [key for key in REQUIRED_KEYS if key not in entries]
    if missing:
        raise BodyModelFileError(
            f"{where}: missing key(s) {', '.join(missing)} (an SMPL model needs {', '.join(REQUIRED_KEYS)})"
        )
    fmt = _metadata_string(entries, "format", where)
    if fmt is not None and fmt != BODY_MODEL_FORMAT:
        raise BodyModelFileError(f"{where}: unknown format {fmt!r} (this reader knows {BODY_MODEL_FORMAT!r})")
    kind = _metadata_string(entries, "body_model", where) or "smpl"
    arrays = {key: _to_array(entries[key], key, where) for key in REQUIRED_KEYS}
    extras = {}
    for key, value in entries.items():
        if key in REQUIRED_KEYS or key in METADATA_KEYS:
            continue
        array = _maybe_array(value, key, where)
        if array is not None:
            extras[key] = array
    return BodyModelData(
        kind=kind,
        v_template=arrays["v_template"],
        shapedirs=arrays["shapedirs"],
        posedirs=arrays["posedirs"],
        J_regressor=arrays["J_regressor"],
        weights=arrays["weights"],
        parents=_parents_from_kintree(arrays["kintree_table"], where),
        faces=arrays["f"],
        extras=extras,
        source=path,
    )


def _metadata_string(entries: dict[str, Any], key: str, where: str) -> str | None:
    """A string entry (``str``, ``bytes`` or a 0-d string array), or None when absent."""
    if key not in entries:
        return None
    value = entries[key]
    if isinstance(value, np.ndarray) and value.ndim == 0 and value.dtype.kind in "US":
        value = value[()]
    if isinstance(value, bytes):
        value = value.decode("utf-8", errors="replace")
    if not isinstance(value, str):
        raise BodyModelFileError(f"{where}: entry {key!r} must be a string, found {type(value).__name__}")
    return str(value)  # plain str, also for numpy.str_


def _parents_from_kintree(kintree: np.ndarray, where: str) -> np.ndarray:
    """kintree_table [2, 24] (parents; joint ids) -> parents [24] int64, checked to be SMPL's tree."""
    if kintree.shape != (2, NUM_JOINTS):
        raise BodyModelFileError(
            f"{where}: kintree_table must be [2, {NUM_JOINTS}] (SMPL's 24-joint tree), found {list(kintree.shape)}"
        )
    integral = kintree.dtype.kind in "iu" or (
        kintree.dtype.kind == "f" and np.all(np.isfinite(kintree)) and np.all(kintree == np.round(kintree))
    )
    if not integral:
        raise BodyModelFileError(f"{where}: kintree_table must hold integer joint indices, found {kintree.dtype}")
    raw = [int(v) for v in kintree[0]]
    if raw[0] not in ROOT_PARENT_CODES:
        raise BodyModelFileError(f"{where}: kintree_table root parent must be -1 (or 4294967295), found {raw[0]}")
    parents = np.array([-1, *raw[1:]], dtype=np.int64)
    joint_ids = [int(v) for v in kintree[1]]
    if tuple(parents.tolist()) != SMPL_PARENTS or joint_ids != list(range(NUM_JOINTS)):
        raise BodyModelFileError(
            f"{where}: kintree_table is not SMPL's 24-joint tree: parents {parents.tolist()}, joint ids {joint_ids} "
            f"(expected parents {list(SMPL_PARENTS)} and ids 0..{NUM_JOINTS - 1})"
        )
    return parents


# --------------------------------------------------------------------------- validation


def _read_only(array: np.ndarray) -> np.ndarray:
    """Mark a freshly made array (never the caller's) read-only."""
    array.flags.writeable = False
    return array


def _float_array(value: Any, name: str, where: str) -> np.ndarray:
    array = np.asarray(value)
    if array.dtype.kind not in "fiu":
        raise BodyModelFileError(f"{where}: {name} must be numeric, found dtype {array.dtype}")
    array = array.astype(np.float64, copy=True)
    if not np.all(np.isfinite(array)):
        bad = int(np.size(array) - np.count_nonzero(np.isfinite(array)))
        raise BodyModelFileError(f"{where}: {name} holds {bad} NaN or infinite value(s)")
    return array


def _check_shape(array: np.ndarray, expected: tuple[int | None, ...], name: str, where: str, hint: str = "") -> None:
    ok = array.ndim == len(expected) and all(e is None or e == s for e, s in zip(expected, array.shape, strict=True))
    if not ok:
        shown = ", ".join("*" if e is None else str(e) for e in expected)
        raise BodyModelFileError(f"{where}: {name} must be [{shown}]{hint}, found {list(array.shape)}")


def _validated_arrays(data: BodyModelData, where: str) -> dict[str, np.ndarray]:
    """Check shapes, finiteness, index ranges and the tree; return float64/int64 read-only arrays."""
    if data.kind not in BODY_MODEL_KINDS:
        raise BodyModelFileError(f"{where}: body_model must be one of {BODY_MODEL_KINDS}, found {data.kind!r}")
    v_template = _float_array(data.v_template, "v_template", where)
    _check_shape(v_template, (None, 3), "v_template", where)
    num_vertices = v_template.shape[0]
    if num_vertices == 0:
        raise BodyModelFileError(f"{where}: v_template has no vertices")

    shapedirs = _float_array(data.shapedirs, "shapedirs", where)
    _check_shape(shapedirs, (num_vertices, 3, None), "shapedirs", where)
    if shapedirs.shape[2] < MIN_SHAPE_COMPONENTS:
        raise BodyModelFileError(
            f"{where}: shapedirs has {shapedirs.shape[2]} shape components, needs at least {MIN_SHAPE_COMPONENTS}"
        )

    posedirs = _float_array(data.posedirs, "posedirs", where)
    if posedirs.shape == (num_vertices * 3, NUM_POSE_FEATURES):
        posedirs = posedirs.reshape(num_vertices, 3, NUM_POSE_FEATURES)
    _check_shape(posedirs, (num_vertices, 3, NUM_POSE_FEATURES), "posedirs", where, f" or [{num_vertices * 3}, 207]")

    J_regressor = _float_array(data.J_regressor, "J_regressor", where)
    _check_shape(J_regressor, (NUM_JOINTS, num_vertices), "J_regressor", where)

    weights = _float_array(data.weights, "weights", where)
    _check_shape(weights, (num_vertices, NUM_JOINTS), "weights", where)
    row_error = np.abs(weights.sum(axis=1) - 1.0)
    if row_error.max() > WEIGHT_SUM_TOLERANCE:
        worst = int(row_error.argmax())
        raise BodyModelFileError(
            f"{where}: skinning weights of vertex {worst} sum to {weights[worst].sum():.6g}; every row must sum to 1"
        )

    parents = np.asarray(data.parents)
    if parents.shape != (NUM_JOINTS,) or tuple(int(p) for p in parents) != SMPL_PARENTS:
        raise BodyModelFileError(f"{where}: parents must be SMPL's tree {list(SMPL_PARENTS)}, found {parents.tolist()}")

    faces = np.asarray(data.faces)
    _check_shape(faces, (None, 3), "f (faces)", where)
    if faces.dtype.kind not in "iu":
        raise BodyModelFileError(f"{where}: faces must hold integer vertex indices, found dtype {faces.dtype}")
    if faces.size and (int(faces.min()) < 0 or int(faces.max()) >= num_vertices):
        raise BodyModelFileError(
            f"{where}: face indices must lie in [0, {num_vertices - 1}], found [{int(faces.min())}, {int(faces.max())}]"
        )
    normalised = {
        "v_template": v_template,
        "shapedirs": shapedirs,
        "posedirs": posedirs,
        "J_regressor": J_regressor,
        "weights": weights,
        "parents": parents.astype(np.int64),
        "faces": faces.astype(np.int64),
    }
    return {name: _read_only(array) for name, array in normalised.items()}


# --------------------------------------------------------------------------- entries -> arrays


def _to_array(value: Any, key: str, where: str) -> np.ndarray:
    """A required entry as an ndarray (chumpy stand-ins resolved, sparse matrices densified)."""
    array = _maybe_array(value, key, where)
    if array is None:
        raise BodyModelFileError(f"{where}: {key} must be an array, found {type(value).__name__}")
    return array


def _maybe_array(value: Any, key: str, where: str) -> np.ndarray | None:
    """ndarray for arrays (numeric or string), chumpy stand-ins and sparse matrices;
    None for other entries (plain strings, dicts, object arrays)."""
    if isinstance(value, _ChumpyStandIn):
        value = value.dense(key, where)
    if scipy.sparse.issparse(value):
        return np.asarray(value.toarray())
    if isinstance(value, np.ndarray) and value.dtype.kind in ARRAY_KINDS:
        return value
    return None


# --------------------------------------------------------------------------- npz


def _read_npz(path: Path) -> dict[str, Any]:
    try:
        with np.load(path, allow_pickle=False) as archive:
            return {key: archive[key] for key in archive.files}
    except ValueError as exc:  # object arrays need pickle: refused
        raise BodyModelFileError(f"{path}: unreadable .npz ({exc}); store plain numeric/string arrays only") from None
    except (OSError, zipfile.BadZipFile, EOFError) as exc:
        raise BodyModelFileError(f"{path}: not a readable .npz archive ({exc})") from None


# --------------------------------------------------------------------------- restricted pickle


class _ChumpyStandIn:
    """Takes the place of any chumpy class while unpickling; keeps the pickled state."""

    chumpy_class = "chumpy.?"

    def __init__(self, *args: Any, **kwargs: Any) -> None:  # chumpy objects are rebuilt from state only
        self.state: Any = None

    def __setstate__(self, state: Any) -> None:
        self.state = state

    def dense(self, key: str, where: str) -> np.ndarray:
        """The dense value: ``Ch`` keeps it under 'x'; ``Select`` indexes its source 'a' by 'idxs'."""
        state = self.state if isinstance(self.state, dict) else {}
        if "x" in state:
            x = state["x"]
            return x.dense(key, where) if isinstance(x, _ChumpyStandIn) else np.asarray(x)
        if "a" in state and "idxs" in state:
            source = state["a"]
            source = source.dense(key, where) if isinstance(source, _ChumpyStandIn) else np.asarray(source)
            values = source.reshape(-1)[np.asarray(state["idxs"], dtype=np.int64).reshape(-1)]
            shape = state.get("preferred_shape")
            return values.reshape(tuple(shape)) if shape is not None else values
        raise BodyModelFileError(
            f"{where}: {key} is a {self.chumpy_class} object whose pickled state holds no array "
            f"(keys {sorted(state)}); re-export the model with plain numpy arrays"
        )


@lru_cache(maxsize=None)
def _chumpy_stand_in(module: str, name: str) -> type[_ChumpyStandIn]:
    return type(name, (_ChumpyStandIn,), {"chumpy_class": f"{module}.{name}"})


def _allowed_globals() -> dict[tuple[str, str], Any]:
    """(module, name) -> object for the non-chumpy globals an SMPL pickle may name.

    numpy's private reconstruction helpers are taken from numpy's own reduce values,
    so the names of both numpy 1 (``numpy.core``) and numpy 2 (``numpy._core``) map to them.
    """
    reconstruct = np.zeros(1).__reduce__()[0]
    scalar = np.float64(0).__reduce__()[0]
    frombuffer = np.zeros(1).__reduce_ex__(5)[0]
    table: dict[tuple[str, str], Any] = {}
    for core in ("numpy.core", "numpy._core"):
        table[(f"{core}.multiarray", "_reconstruct")] = reconstruct
        table[(f"{core}.multiarray", "scalar")] = scalar
        table[(f"{core}.numeric", "_frombuffer")] = frombuffer
    table[("numpy", "ndarray")] = np.ndarray
    table[("numpy", "dtype")] = np.dtype
    for builtins_module in ("__builtin__", "builtins"):  # Python 2 and 3 spellings
        for name, value in (("set", set), ("frozenset", frozenset), ("object", object), ("slice", slice)):
            table[(builtins_module, name)] = value
    table[("copy_reg", "_reconstructor")] = copyreg._reconstructor  # Python 2 protocol 0/1 objects
    table[("copyreg", "_reconstructor")] = copyreg._reconstructor
    table[("_codecs", "encode")] = codecs.encode  # bytes written by Python 3 at protocol < 3
    return table


_SPARSE_CLASSES = ("csc_matrix", "csr_matrix", "coo_matrix", "csc_array", "csr_array", "coo_array")


class _RestrictedUnpickler(pickle.Unpickler):
    """Unpickler that only builds numpy arrays, scipy.sparse matrices and chumpy stand-ins."""

    def __init__(self, file: Any, where: str) -> None:
        super().__init__(file, encoding="latin1")  # official files were pickled by Python 2
        self._where = where
        self._allowed = _allowed_globals()

    def find_class(self, module: str, name: str) -> Any:
        if module == "chumpy" or module.startswith("chumpy."):
            return _chumpy_stand_in(module, name)
        if (module == "scipy.sparse" or module.startswith("scipy.sparse.")) and name in _SPARSE_CLASSES:
            return getattr(scipy.sparse, name)
        if (module, name) in self._allowed:
            return self._allowed[(module, name)]
        raise BodyModelFileError(
            f"{self._where}: refusing to unpickle {module}.{name}: a model pickle may only hold numpy arrays, "
            "scipy.sparse matrices and chumpy objects (unpickling other classes can run arbitrary code)"
        )


def _read_pickle(path: Path) -> dict[str, Any]:
    where = str(path)
    try:
        with open(path, "rb") as handle:
            entries = _RestrictedUnpickler(handle, where).load()
    except BodyModelFileError:
        raise
    except Exception as exc:  # truncated or corrupt pickles raise many different types
        raise BodyModelFileError(f"{where}: not a readable model pickle ({type(exc).__name__}: {exc})") from None
    if not isinstance(entries, dict):
        raise BodyModelFileError(f"{where}: the pickle holds a {type(entries).__name__}, expected a dict of arrays")
    return {str(key): value for key, value in entries.items()}
