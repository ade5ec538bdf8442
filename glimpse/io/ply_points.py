"""Coloured point clouds as binary PLY (x y z, nx ny nz, red green blue), the layout
the 3DGS reference code reads for initialisation, with Glimpse's version comment."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from glimpse.errors import GlimpseError

POINTS_FORMAT = "glimpse-points/1"
_DTYPE = np.dtype(
    [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4"),
     ("red", "u1"), ("green", "u1"), ("blue", "u1")]
)


def write_points_ply(path: Path, xyz: np.ndarray, rgb: np.ndarray) -> None:
    """xyz: (N, 3) float positions (world frame); rgb: (N, 3) uint8 colours."""
    xyz, rgb = np.asarray(xyz), np.asarray(rgb)
    if xyz.ndim != 2 or xyz.shape[1] != 3 or rgb.shape != xyz.shape:
        raise ValueError(f"expected xyz (N, 3) and rgb (N, 3), found {xyz.shape} and {rgb.shape}")
    data = np.zeros(len(xyz), dtype=_DTYPE)
    data["x"], data["y"], data["z"] = xyz.T.astype(np.float32)
    data["red"], data["green"], data["blue"] = rgb.T.astype(np.uint8)
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"comment glimpse-format {POINTS_FORMAT}\n"
        f"element vertex {len(data)}\n"
        + "".join(f"property {'float' if data.dtype[n].kind == 'f' else 'uchar'} {n}\n" for n in data.dtype.names)
        + "end_header\n"
    )
    with Path(path).open("wb") as f:
        f.write(header.encode("ascii"))
        f.write(data.tobytes())


def read_points_ply(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a file written by write_points_ply: (xyz (N, 3) float32, rgb (N, 3) uint8)."""
    raw = Path(path).read_bytes()
    end = raw.find(b"end_header\n")
    if end < 0:
        raise GlimpseError(f"{path}: not a PLY file (no end_header)")
    header = raw[:end].decode("ascii", errors="replace").splitlines()
    if f"comment glimpse-format {POINTS_FORMAT}" not in header:
        raise GlimpseError(f"{path}: expected a '{POINTS_FORMAT}' PLY (comment glimpse-format ...)")
    count = next(int(line.split()[2]) for line in header if line.startswith("element vertex"))
    data = np.frombuffer(raw[end + len(b"end_header\n"):], dtype=_DTYPE, count=count)
    xyz = np.stack([data["x"], data["y"], data["z"]], axis=1)
    rgb = np.stack([data["red"], data["green"], data["blue"]], axis=1)
    return xyz, rgb
