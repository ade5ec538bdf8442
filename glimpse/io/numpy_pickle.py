"""Reading pickled numpy data without running code: an Unpickler that builds numpy arrays, dtypes and
scalars inside plain containers (dict, list, tuple, str, numbers) and refuses every other class, and with it
the ``.npy`` files that ``np.save`` writes for objects (datasets' dicts of arrays, e.g. ZJU-MoCap's
annots.npy), which ``np.load`` reads only by allowing unrestricted pickle, and the files ``joblib.dump``
writes (NeuMan's SMPL files), which ``joblib.load`` reads by unrestricted pickle too.

joblib's format (joblib >= 0.10, read from its numpy_pickle module): a pickle stream in which every numpy
array is pickled as a ``joblib.numpy_pickle.NumpyArrayWrapper`` object (its state: subclass, shape, order,
dtype and, since joblib 1.2, an alignment) followed, outside the pickle's frames, by the array's raw bytes
(after one byte giving a padding length and that many padding bytes, when the state names an alignment).
A compressed dump is the same stream inside a zlib, gzip, bz2 or xz container.
"""

from __future__ import annotations

import bz2
import gzip
import io
import lzma
import pickle
import zipfile
import zlib
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from numpy.lib import format as npy_format

from glimpse.errors import GlimpseError

ALLOWED = {(module, name) for module in ("numpy.core.multiarray", "numpy._core.multiarray")
           for name in ("_reconstruct", "scalar")} | {("numpy", "ndarray"), ("numpy", "dtype"),
                                                      ("_codecs", "encode")}  # bytes, in pickle protocols 0-2
JOBLIB_ARRAY = ("joblib.numpy_pickle", "NumpyArrayWrapper")
# joblib's compress= containers: magic prefix -> decompressor (gzip, bz2, xz, lzma, zlib)
JOBLIB_CONTAINERS = ((b"\x1f\x8b", gzip.decompress), (b"BZh", bz2.decompress), (b"\xfd7zXZ", lzma.decompress),
                     (b"\x5d\x00", lzma.decompress), (b"\x78", zlib.decompress))
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


class JoblibArrayRecord:
    """What a joblib file pickles in place of an array (its state: shape, order, dtype, alignment), read into
    the array by JoblibUnpickler as soon as the state is set."""


class JoblibUnpickler(pickle._Unpickler):
    """Unpickles a ``joblib.dump`` stream of numpy arrays in plain containers, and nothing else. Built on the
    Python unpickler (as joblib is): its opcode table can be extended, and it reads no further ahead than the
    opcode it is at, so a record's array bytes are next in the file when its state is set."""

    dispatch = dict(pickle._Unpickler.dispatch)

    def __init__(self, file: BinaryIO, where: str) -> None:
        super().__init__(file)
        self.file, self.where = file, where

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) == JOBLIB_ARRAY:
            return JoblibArrayRecord
        if (module, name) not in ALLOWED:
            raise pickle.UnpicklingError(f"{self.where}: refusing to unpickle {module}.{name} (only numpy arrays "
                                         "in plain containers are read: other classes can run code)")
        return super().find_class(module, name)

    def load_build(self) -> None:
        super().load_build()
        if isinstance(self.stack[-1], JoblibArrayRecord):
            self.stack.append(self.read_array(vars(self.stack.pop())))

    dispatch[pickle.BUILD[0]] = load_build

    def read_array(self, state: dict[str, Any]) -> np.ndarray:
        """The array whose raw bytes follow in the file, from its record's ``state``."""
        dtype, shape = np.dtype(state["dtype"]), tuple(int(n) for n in state["shape"])
        if dtype.hasobject:
            raise pickle.UnpicklingError(f"{self.where}: an array of Python objects (only numeric arrays are read)")
        if state.get("numpy_array_alignment_bytes") is not None:
            self.file.read(self.file.read(1)[0])
        count = int(np.prod(shape, dtype=np.int64))
        data = self.file.read(count * dtype.itemsize)
        if len(data) != count * dtype.itemsize:
            raise EOFError(f"{self.where}: the file ends inside an array's data")
        array = np.frombuffer(data, dtype=dtype, count=count)
        array = array.reshape(shape[::-1]).T if state.get("order") == "F" else array.reshape(shape)
        return array.astype(dtype.newbyteorder("="), copy=True)


def load_joblib_pickle(path: Path) -> Any:
    """The object ``joblib.dump`` stored in ``path`` (uncompressed or in any of joblib's containers), numpy
    arrays in plain containers only. Raises GlimpseError for anything else, naming the file."""
    try:
        raw = Path(path).read_bytes()
        for magic, decompress in JOBLIB_CONTAINERS:
            if raw.startswith(magic):
                raw = decompress(raw)
                break
        return JoblibUnpickler(io.BytesIO(raw), str(path)).load()
    except (OSError, ValueError, pickle.UnpicklingError, EOFError, IndexError, KeyError, TypeError,
            zlib.error, lzma.LZMAError) as exc:
        raise GlimpseError(f"{path}: not a readable joblib file of numpy arrays ({exc})") from None


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
