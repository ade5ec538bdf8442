"""Reading pickled numpy data without running code: an Unpickler that builds numpy arrays, dtypes and
scalars inside plain containers (dict, list, tuple, str, numbers) and refuses every other class, and with it
the ``.npy`` files that ``np.save`` writes for objects (datasets' dicts of arrays, e.g. ZJU-MoCap's
annots.npy), which ``np.load`` reads only by allowing unrestricted pickle."""

from __future__ import annotations

import io
import pickle
import zipfile
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from numpy.lib import format as npy_format

from glimpse.errors import GlimpseError

ALLOWED = {(module, name) for module in ("numpy.core.multiarray", "numpy._core.multiarray")
           for name in ("_reconstruct", "scalar")} | {("numpy", "ndarray"), ("numpy", "dtype")}
HEADER_READERS = {(1, 0): npy_format.read_array_header_1_0, (2, 0): npy_format.read_array_header_2_0}


class NumpyOnlyUnpickler(pickle.Unpickler):
    """Unpickles numpy arrays in plain containers, and nothing else."""

    def __init__(self, file: BinaryIO, where: str, encoding: str = "ASCII") -> None:
        super().__init__(file, encoding=encoding)
        self.where = where

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) not in ALLOWED:
            raise pickle.UnpicklingError(f"{self.where}: refusing to unpickle {module}.{name} (only numpy arrays "
                                         "in plain containers are read: other classes can run code)")
        return super().find_class(module, name)


def load_numpy_pickle(handle: BinaryIO, where: str) -> Any:
    """The object pickled in ``handle`` (numpy arrays in plain containers only)."""
    return NumpyOnlyUnpickler(handle, where).load()


def read_npy(handle: BinaryIO, where: str) -> Any:
    """The array stored in an open .npy stream (an object array through NumpyOnlyUnpickler); a 0-d object
    array gives its object (a dict, usually)."""
    version = npy_format.read_magic(handle)
    if version not in HEADER_READERS:
        raise ValueError(f"npy format version {version} is not read here")
    shape, fortran_order, dtype = HEADER_READERS[version](handle)
    if dtype.hasobject:
        array = NumpyOnlyUnpickler(handle, where, encoding="latin1").load()
    else:
        data = np.frombuffer(handle.read(), dtype=dtype, count=int(np.prod(shape, dtype=np.int64)))
        array = data.reshape(shape[::-1]).T if fortran_order else data.reshape(shape)
    return array.item() if isinstance(array, np.ndarray) and array.dtype.hasobject and array.shape == () else array


def load_object_npy(path: Path) -> Any:
    """What ``np.save`` stored in ``path`` (read_npy). Raises GlimpseError for a file that is not a .npy or holds
    other classes than numpy's."""
    try:
        with open(path, "rb") as handle:
            return read_npy(handle, str(path))
    except (OSError, ValueError, pickle.UnpicklingError, EOFError) as exc:
        raise GlimpseError(f"{path}: not a readable .npy of numpy arrays ({exc})") from None


def load_object_npz(path: Path) -> dict[str, Any]:
    """Every entry of an .npz (``np.savez``), object entries included, read as read_npy does."""
    try:
        with zipfile.ZipFile(path) as archive:
            entries = {}
            for name in archive.namelist():
                with archive.open(name) as member:
                    entries[name.removesuffix(".npy")] = read_npy(io.BytesIO(member.read()), f"{path}:{name}")
            return entries
    except (OSError, ValueError, pickle.UnpicklingError, EOFError, zipfile.BadZipFile) as exc:
        raise GlimpseError(f"{path}: not a readable .npz of numpy arrays ({exc})") from None
