"""Tests of glimpse.gaussians.ply: round trips, the INRIA byte layout, foreign files, errors."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import torch
from numpy.lib.recfunctions import repack_fields

from glimpse.errors import GlimpseError
from glimpse.gaussians.ply import (
    GAUSSIANS_FORMAT,
    GaussianSplats,
    GaussiansFileError,
    read_gaussians_ply,
    write_gaussians_ply,
)

DEGREES = [0, 1, 2, 3]
SIZES = [0, 1, 1000]
FIELDS = ("means", "sh", "opacity_logits", "log_scales", "quats")


def _random_splats(n: int, degree: int, seed: int = 0) -> GaussianSplats:
    rng = np.random.default_rng(seed)
    k = (degree + 1) ** 2
    # Include awkward float32 values: denormals, -0.0, huge, inf (only NaN is refused).
    means = rng.normal(size=(n, 3)).astype(np.float32)
    if n:
        means[0] = [np.float32(1e-45), np.float32(-0.0), np.float32(3e38)]
        means[-1, 0] = np.inf
    return GaussianSplats(
        means=means,
        sh=rng.normal(size=(n, k, 3)).astype(np.float32),
        opacity_logits=rng.normal(size=n).astype(np.float32),
        log_scales=rng.normal(-4.0, 1.0, size=(n, 3)).astype(np.float32),
        quats=rng.normal(size=(n, 4)).astype(np.float32),
    )


def _assert_bit_identical(a: GaussianSplats, b: GaussianSplats) -> None:
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype == np.float32, name
        assert x.shape == y.shape, name
        assert x.tobytes() == y.tobytes(), name


def _inria_property_names(num_rest: int) -> list[str]:
    """The attribute list of INRIA's GaussianModel.construct_list_of_attributes, by hand."""
    return (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(num_rest)]
        + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    )


def _inria_records(splats: GaussianSplats) -> np.ndarray:
    """Independent writer: a structured array as INRIA's save_ply fills it.

    features_rest is kept as [N, K-1, 3] (INRIA's _features_rest); save_ply transposes it
    to [N, 3, K-1] and flattens, so we do the same here field by field.
    """
    n, k = splats.sh.shape[:2]
    names = _inria_property_names(3 * (k - 1))
    rec = np.zeros(n, dtype=[(name, "<f4") for name in names])
    for i, axis in enumerate("xyz"):
        rec[axis] = splats.means[:, i]
        rec[f"scale_{i}"] = splats.log_scales[:, i]
    for c in range(3):
        rec[f"f_dc_{c}"] = splats.sh[:, 0, c]
        for j in range(k - 1):  # rest coefficient j+1 of channel c
            rec[f"f_rest_{c * (k - 1) + j}"] = splats.sh[:, j + 1, c]
    rec["opacity"] = splats.opacity_logits
    for i in range(4):
        rec[f"rot_{i}"] = splats.quats[:, i]
    return rec


def _split_header(raw: bytes) -> tuple[list[str], bytes]:
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    return raw[:end].decode("ascii").splitlines(), raw[end:]


def _foreign_ply(records: np.ndarray, comments: list[str] = (), fmt: str = "binary_little_endian") -> bytes:
    """A PLY as another exporter (plyfile) would write it: no Glimpse comment."""
    type_names = {"f4": "float", "f8": "double", "u1": "uchar", "i4": "int"}
    lines = ["ply", f"format {fmt} 1.0", *(f"comment {c}" for c in comments), f"element vertex {len(records)}"]
    lines += [f"property {type_names[records.dtype[n].str[1:]]} {n}" for n in records.dtype.names]
    header = ("\n".join(lines) + "\nend_header\n").encode("ascii")
    if fmt == "ascii":
        body = "".join(" ".join(repr(v.item()) for v in row) + "\n" for row in records)
        return header + body.encode("ascii")
    order = ">" if fmt == "binary_big_endian" else "<"
    return header + records.astype(records.dtype.newbyteorder(order)).tobytes()


# --- round trips and layout -------------------------------------------------------------


@pytest.mark.parametrize("degree", DEGREES)
@pytest.mark.parametrize("n", SIZES)
def test_round_trip_is_bit_identical(tmp_path: Path, degree: int, n: int) -> None:
    splats = _random_splats(n, degree, seed=10 * degree + n)
    path = tmp_path / "splats.ply"
    write_gaussians_ply(path, splats, {"sh_degree": str(degree), "body_model": "smpl neutral v1.1"})
    back, metadata = read_gaussians_ply(path)
    _assert_bit_identical(back, splats)
    assert back.sh_degree == degree and len(back) == n
    assert metadata == {"sh_degree": str(degree), "body_model": "smpl neutral v1.1"}


@pytest.mark.parametrize("degree", DEGREES)
def test_bytes_match_independent_inria_layout(tmp_path: Path, degree: int) -> None:
    splats = _random_splats(37, degree, seed=degree)
    path = tmp_path / "point_cloud.ply"
    write_gaussians_ply(path, splats, {"note": "x"})
    header, body = _split_header(path.read_bytes())
    num_rest = 3 * ((degree + 1) ** 2 - 1)
    assert num_rest in (0, 9, 24, 45)
    assert header == [
        "ply",
        "format binary_little_endian 1.0",
        "comment glimpse-format glimpse-gaussians/1",
        "comment glimpse-note x",
        "element vertex 37",
        *(f"property float {name}" for name in _inria_property_names(num_rest)),
        "end_header",
    ]
    expected = _inria_records(splats)
    assert len(body) == 37 * 4 * (17 + num_rest)
    assert body == expected.tobytes()
    # Normals are zeros.
    rec = np.frombuffer(body, dtype=expected.dtype)
    assert not rec["nx"].any() and not rec["ny"].any() and not rec["nz"].any()


def test_f_rest_is_channel_major_on_a_hand_made_example(tmp_path: Path) -> None:
    """Degree 1: sh[0, k, c] = 10*c + k, so f_rest must read R1 R2 R3 G1 G2 G3 B1 B2 B3."""
    sh = np.array([[[10.0 * c + k for c in range(3)] for k in range(4)]], dtype=np.float32)  # [1, 4, 3]
    splats = GaussianSplats(
        means=np.zeros((1, 3)), sh=sh, opacity_logits=np.zeros(1), log_scales=np.zeros((1, 3)),
        quats=np.array([[1.0, 0.0, 0.0, 0.0]]),
    )  # fmt: skip
    path = tmp_path / "one.ply"
    write_gaussians_ply(path, splats)
    _, body = _split_header(path.read_bytes())
    values = np.frombuffer(body, dtype="<f4")
    # x y z nx ny nz | f_dc_0..2 | f_rest_0..8 | opacity | scale_0..2 | rot_0..3
    np.testing.assert_array_equal(values[6:9], [0.0, 10.0, 20.0])
    np.testing.assert_array_equal(values[9:18], [1, 2, 3, 11, 12, 13, 21, 22, 23])
    np.testing.assert_array_equal(values[18:], [0, 0, 0, 0, 1, 0, 0, 0])
    back, _ = read_gaussians_ply(path)
    np.testing.assert_array_equal(back.sh, sh)


def test_write_is_atomic_and_leaves_no_temp_files(tmp_path: Path) -> None:
    path = tmp_path / "s.ply"
    path.write_bytes(b"old")
    write_gaussians_ply(path, _random_splats(5, 2))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.ply"]
    # A failed write (NaN) leaves the old file untouched and no temp file behind.
    bad = _random_splats(5, 2)
    bad.quats[3, 1] = np.nan
    before = path.read_bytes()
    with pytest.raises(GaussiansFileError, match=r"quats has NaN .* index 3"):
        write_gaussians_ply(path, bad)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.ply"]
    # Permissions follow the umask like any new file (not mkstemp's 0600).
    umask = os.umask(0)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask


def test_bad_metadata_is_refused(tmp_path: Path) -> None:
    splats = _random_splats(2, 0)
    for metadata in ({"format": "x"}, {"two words": "x"}, {"k": "line\nbreak"}, {"k": "caf\u00e9"}, {"k": 3}):
        with pytest.raises(GaussiansFileError):
            write_gaussians_ply(tmp_path / "m.ply", splats, metadata)  # type: ignore[arg-type]
    with pytest.raises(GaussiansFileError, match="sh_degree"):
        write_gaussians_ply(tmp_path / "m.ply", splats, {"sh_degree": "3"})
    assert not list(tmp_path.iterdir())


def test_splats_validate_shapes_and_coerce_dtype() -> None:
    s = _random_splats(4, 1)
    as64 = GaussianSplats(s.means.astype(np.float64), s.sh, s.opacity_logits, s.log_scales, s.quats)
    assert as64.means.dtype == np.float32
    with pytest.raises(ValueError, match="quats"):
        GaussianSplats(s.means, s.sh, s.opacity_logits, s.log_scales, s.quats[:, :3])
    with pytest.raises(ValueError, match="opacity_logits"):
        GaussianSplats(s.means, s.sh, s.opacity_logits[:3], s.log_scales, s.quats)
    with pytest.raises(ValueError, match="sh"):
        GaussianSplats(s.means, np.zeros((4, 5, 3)), s.opacity_logits, s.log_scales, s.quats)


def test_torch_conversions() -> None:
    s = GaussianSplats(
        means=np.array([[1.0, 2.0, 3.0]]), sh=np.zeros((1, 1, 3)), opacity_logits=np.array([0.0]),
        log_scales=np.log(np.array([[0.5, 1.0, 2.0]])), quats=np.array([[2.0, 0.0, 0.0, 0.0]]),
    )  # fmt: skip
    torch.testing.assert_close(s.opacities(), torch.tensor([0.5]))
    torch.testing.assert_close(s.scales(), torch.tensor([[0.5, 1.0, 2.0]]))
    torch.testing.assert_close(s.normalized_quats(), torch.tensor([[1.0, 0.0, 0.0, 0.0]]))
    assert s.means_tensor().dtype == torch.float32 and s.sh_tensor().shape == (1, 1, 3)
    r = _random_splats(6, 3)
    torch.testing.assert_close(r.normalized_quats().norm(dim=-1), torch.ones(6))
    back = GaussianSplats.from_tensors(
        torch.from_numpy(r.means).requires_grad_(True), torch.from_numpy(r.sh),
        torch.from_numpy(r.opacity_logits)[:, None], torch.from_numpy(r.log_scales), torch.from_numpy(r.quats),
    )  # fmt: skip
    _assert_bit_identical(back, r)


# --- files from other exporters ---------------------------------------------------------


def _with_colours(records: np.ndarray) -> np.ndarray:
    """Insert uchar red green blue after the normals and a double 'extra' at the end."""
    names = list(records.dtype.names)
    at = names.index("nz") + 1
    dtype = [(n, "<f4") for n in names[:at]] + [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    dtype += [(n, "<f4") for n in names[at:]] + [("extra", "<f8")]
    out = np.zeros(len(records), dtype=dtype)
    for n in names:
        out[n] = records[n]
    out["red"], out["green"], out["blue"], out["extra"] = 255, 7, 1, 1e300
    return out


@pytest.mark.parametrize("degree", DEGREES)
def test_reads_plain_inria_export(tmp_path: Path, degree: int) -> None:
    splats = _random_splats(50, degree, seed=3)
    path = tmp_path / "point_cloud.ply"
    path.write_bytes(_foreign_ply(_inria_records(splats)))
    back, metadata = read_gaussians_ply(path)
    _assert_bit_identical(back, splats)
    assert metadata == {}


@pytest.mark.parametrize("fmt", ["binary_little_endian", "binary_big_endian", "ascii"])
def test_reads_other_exporter_with_extra_properties(tmp_path: Path, fmt: str) -> None:
    splats = _random_splats(20, 3, seed=4)
    splats.means[-1, 0] = 1.5  # no inf in ASCII
    path = tmp_path / "export.ply"
    comments = ["Generated by SomeViewer", "vertices 20"]
    path.write_bytes(_foreign_ply(_with_colours(_inria_records(splats)), comments, fmt))
    back, metadata = read_gaussians_ply(path)
    _assert_bit_identical(back, splats)
    assert metadata == {}


def test_reads_file_without_normals_and_with_other_elements(tmp_path: Path) -> None:
    splats = _random_splats(8, 1, seed=5)
    rec = _inria_records(splats)
    keep = [n for n in rec.dtype.names if n not in ("nx", "ny", "nz")]
    rec = repack_fields(rec[keep])
    cams = np.arange(2 * 3, dtype="<f4").reshape(2, 3)
    header = (
        "ply\nformat binary_little_endian 1.0\nelement camera 2\nproperty float a\nproperty float b\n"
        "property float c\nelement vertex 8\n"
        + "".join(f"property float {n}\n" for n in keep)
        + "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
    )
    tail = np.array([3], "u1").tobytes() + np.array([0, 1, 2], "<i4").tobytes()
    path = tmp_path / "mixed.ply"
    path.write_bytes(header.encode() + cams.tobytes() + rec.tobytes() + tail)
    back, _ = read_gaussians_ply(path)
    _assert_bit_identical(back, splats)


# --- refusals ---------------------------------------------------------------------------


def _written(tmp_path: Path, n: int = 10, degree: int = 2) -> tuple[Path, bytes]:
    path = tmp_path / "g.ply"
    write_gaussians_ply(path, _random_splats(n, degree))
    return path, path.read_bytes()


def test_unknown_glimpse_format_version_is_refused(tmp_path: Path) -> None:
    path, raw = _written(tmp_path)
    path.write_bytes(raw.replace(b"glimpse-gaussians/1", b"glimpse-gaussians/2"))
    with pytest.raises(GaussiansFileError, match=r"g\.ply: unknown version 'glimpse-gaussians/2'"):
        read_gaussians_ply(path)
    path.write_bytes(raw.replace(b"glimpse-gaussians/1", b"glimpse-points/1xx"))
    with pytest.raises(GaussiansFileError, match="glimpse-format is 'glimpse-points/1xx', not glimpse-gaussians/1"):
        read_gaussians_ply(path)
    assert GAUSSIANS_FORMAT == "glimpse-gaussians/1"


@pytest.mark.parametrize("cut", [1, 4, 500])
def test_truncated_file_is_refused(tmp_path: Path, cut: int) -> None:
    path, raw = _written(tmp_path)
    path.write_bytes(raw[:-cut])
    with pytest.raises(GaussiansFileError, match=r"g\.ply: truncated") as info:
        read_gaussians_ply(path)
    assert isinstance(info.value, GlimpseError)


def test_truncated_header_and_not_ply_are_refused(tmp_path: Path) -> None:
    path, raw = _written(tmp_path)
    path.write_bytes(raw[: raw.index(b"end_header")])
    with pytest.raises(GaussiansFileError, match="end_header"):
        read_gaussians_ply(path)
    path.write_bytes(b"PK\x03\x04 not a ply")
    with pytest.raises(GaussiansFileError, match="not a PLY"):
        read_gaussians_ply(path)
    with pytest.raises(GaussiansFileError, match="missing.ply"):
        read_gaussians_ply(tmp_path / "missing.ply")


def test_truncated_ascii_is_refused(tmp_path: Path) -> None:
    splats = _random_splats(5, 0, seed=6)
    splats.means[-1, 0] = 0.0
    raw = _foreign_ply(_inria_records(splats), fmt="ascii")
    path = tmp_path / "a.ply"
    path.write_bytes(raw[: raw.rstrip(b"\n").rindex(b"\n") + 1])  # drop the last vertex line
    with pytest.raises(GaussiansFileError, match="truncated"):
        read_gaussians_ply(path)


def test_missing_property_is_refused(tmp_path: Path) -> None:
    path, raw = _written(tmp_path)
    path.write_bytes(raw.replace(b"property float rot_3\n", b"property float rot_x\n"))
    with pytest.raises(GaussiansFileError, match=r"g\.ply: .*lacks .*rot_3"):
        read_gaussians_ply(path)


def test_bad_f_rest_count_is_refused(tmp_path: Path) -> None:
    splats = _random_splats(4, 1)
    rec = _inria_records(splats)
    keep = [n for n in rec.dtype.names if n != "f_rest_8"]  # 8 f_rest properties
    path = tmp_path / "rest.ply"
    path.write_bytes(_foreign_ply(repack_fields(rec[keep])))
    expected = r"rest\.ply: 8 f_rest_\* properties; expected one of \[0, 9, 24, 45\]"
    with pytest.raises(GaussiansFileError, match=expected):
        read_gaussians_ply(path)


def test_nan_is_refused(tmp_path: Path) -> None:
    splats = _random_splats(6, 1)
    rec = _inria_records(splats)
    rec["f_rest_4"][2] = np.nan
    path = tmp_path / "nan.ply"
    path.write_bytes(_foreign_ply(rec))
    with pytest.raises(GaussiansFileError, match=r"nan\.ply: sh has NaN for 1 Gaussian\(s\), first at index 2"):
        read_gaussians_ply(path)


def test_inconsistent_sh_degree_metadata_is_refused(tmp_path: Path) -> None:
    path, raw = _written(tmp_path, degree=2)
    path.write_bytes(raw.replace(b"comment glimpse-format glimpse-gaussians/1\n",
                                 b"comment glimpse-format glimpse-gaussians/1\ncomment glimpse-sh_degree 3\n"))
    with pytest.raises(GaussiansFileError, match="sh_degree"):
        read_gaussians_ply(path)
