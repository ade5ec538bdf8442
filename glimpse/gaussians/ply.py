"""Gaussian splats as a standard 3DGS PLY file (``glimpse-gaussians/1``).

The layout is the one INRIA's ``GaussianModel.save_ply`` writes and gsplat's exporter,
SuperSplat and other viewers read::

    ply
    format binary_little_endian 1.0
    comment glimpse-format glimpse-gaussians/1      <- Glimpse only (viewers ignore comments)
    comment glimpse-<key> <value>                   <- optional metadata, one line per key
    element vertex N
    property float x            \\
    property float y             | means, metres
    property float z            /
    property float nx / ny / nz   zeros (unused normals)
    property float f_dc_0..2      DC SH coefficient of R, G, B
    property float f_rest_0..M-1  M = 3 (K-1) = 0, 9, 24 or 45 for SH degree 0..3
    property float opacity        pre-sigmoid logit
    property float scale_0..2     log-scales
    property float rot_0..3       quaternion w, x, y, z (not necessarily normalised)
    end_header
    <N records of float32, little-endian, in that order>

``f_rest`` is *channel-major*: INRIA keeps the higher-order coefficients as
``[N, K-1, 3]``, transposes them to ``[N, 3, K-1]`` and flattens, so ``f_rest_0 ..
f_rest_{K-2}`` are the red coefficients 1..K-1, then green, then blue.

The reader also takes files from other exporters: no Glimpse comment, extra vertex
properties (e.g. ``red green blue``, ignored), no normals, other numeric property
types (converted to float32), ASCII or big-endian PLY, and other elements. It refuses a
``glimpse-format`` comment naming another format or version.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from glimpse.errors import GlimpseError
from glimpse.io.staging import staged_file

GAUSSIANS_FORMAT = "glimpse-gaussians/1"
FORMAT_FAMILY = "glimpse-gaussians/"
MAX_SH_DEGREE = 3
NUM_COLOUR_CHANNELS = 3
SPATIAL_DIMS = 3
QUAT_DIMS = 4  # w, x, y, z
VERTEX_ELEMENT = "vertex"
FLOAT32 = np.dtype("<f4")

# Header vocabulary.
PLY_MAGIC = "ply"
END_HEADER = "end_header"
BINARY_LE = "binary_little_endian"
BINARY_BE = "binary_big_endian"
ASCII = "ascii"
PLY_VERSION = "1.0"
COMMENT = "comment"
METADATA_PREFIX = "glimpse-"
FORMAT_KEY = "format"
# Metadata keys: one header token; values: printable ASCII on one line.
METADATA_KEY_PATTERN = re.compile(r"[A-Za-z0-9_.\-]+")
METADATA_VALUE_PATTERN = re.compile(r"[\x20-\x7e]*")
SH_DEGREE_KEY = "sh_degree"  # optional metadata, checked against the f_rest count

# PLY scalar types (both spellings of the spec) -> numpy dtype (without byte order).
PLY_SCALAR_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip

POSITION_NAMES = ("x", "y", "z")
NORMAL_NAMES = ("nx", "ny", "nz")
DC_NAMES = tuple(f"f_dc_{c}" for c in range(NUM_COLOUR_CHANNELS))
OPACITY_NAME = "opacity"
SCALE_NAMES = tuple(f"scale_{i}" for i in range(SPATIAL_DIMS))
ROT_NAMES = tuple(f"rot_{i}" for i in range(QUAT_DIMS))
REST_PREFIX = "f_rest_"
# Number of f_rest properties for SH degree 0..3: 3 * ((d+1)^2 - 1).
_NUM_SH_COEFFS = tuple((d + 1) ** 2 for d in range(MAX_SH_DEGREE + 1))  # K = 1, 4, 9, 16
REST_COUNTS = tuple(NUM_COLOUR_CHANNELS * (k - 1) for k in _NUM_SH_COEFFS)  # 0, 9, 24, 45


class GaussiansFileError(GlimpseError, ValueError):
    """A Gaussians PLY file cannot be read or written; the message names the file."""


@dataclass
class GaussianSplats:
    """Raw (pre-activation) 3DGS parameters of N Gaussians, exactly as stored.

    Arrays are coerced to C-contiguous float32 on construction and their shapes checked
    (ValueError otherwise).
    """

    means: np.ndarray  # [N, 3] float32, metres
    sh: np.ndarray  # [N, K, 3] float32, K = (degree+1)^2; sh[:, 0] is the DC term
    opacity_logits: np.ndarray  # [N] float32, opacity = sigmoid(logit)
    log_scales: np.ndarray  # [N, 3] float32, scale = exp(log_scale), metres
    quats: np.ndarray  # [N, 4] float32, w x y z, not necessarily normalised

    def __post_init__(self) -> None:
        for name in ("means", "sh", "opacity_logits", "log_scales", "quats"):
            setattr(self, name, np.ascontiguousarray(getattr(self, name), dtype=np.float32))
        n = self.means.shape[0] if self.means.ndim == 2 else -1
        expected = {
            "means": (n, SPATIAL_DIMS),
            "opacity_logits": (n,),
            "log_scales": (n, SPATIAL_DIMS),
            "quats": (n, QUAT_DIMS),
        }
        for name, shape in expected.items():
            found = getattr(self, name).shape
            if found != shape:
                raise ValueError(f"GaussianSplats.{name} must have shape {shape} (N from means [N, 3]), got {found}")
        k = self.sh.shape[1] if self.sh.ndim == 3 else -1
        if self.sh.shape != (n, k, NUM_COLOUR_CHANNELS) or k not in _NUM_SH_COEFFS:
            raise ValueError(
                f"GaussianSplats.sh must have shape (N, K, 3) with N = {n}, K in {_NUM_SH_COEFFS}, got {self.sh.shape}"
            )

    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def sh_degree(self) -> int:
        """SH degree, 0..3, implied by K = sh.shape[1] = (degree+1)^2."""
        return _NUM_SH_COEFFS.index(self.sh.shape[1])

    # --- conversions for the renderer (torch) ---------------------------------------

    def means_tensor(self, device: torch.device | str | None = None) -> torch.Tensor:
        """[N, 3] float32 means, metres."""
        return torch.as_tensor(self.means, device=device)

    def sh_tensor(self, device: torch.device | str | None = None) -> torch.Tensor:
        """[N, K, 3] float32 SH coefficients (for glimpse.render.sh.sh_to_rgb)."""
        return torch.as_tensor(self.sh, device=device)

    def opacities(self, device: torch.device | str | None = None) -> torch.Tensor:
        """[N] float32 activated opacities in (0, 1): sigmoid(opacity_logits)."""
        return torch.sigmoid(torch.as_tensor(self.opacity_logits, device=device))

    def scales(self, device: torch.device | str | None = None) -> torch.Tensor:
        """[N, 3] float32 activated scales (standard deviations), metres: exp(log_scales)."""
        return torch.exp(torch.as_tensor(self.log_scales, device=device))

    def normalized_quats(self, device: torch.device | str | None = None) -> torch.Tensor:
        """[N, 4] float32 unit quaternions w, x, y, z (a zero quaternion stays zero)."""
        return F.normalize(torch.as_tensor(self.quats, device=device), dim=-1)

    @classmethod
    def from_tensors(
        cls,
        means: torch.Tensor,
        sh: torch.Tensor,
        opacity_logits: torch.Tensor,
        log_scales: torch.Tensor,
        quats: torch.Tensor,
    ) -> GaussianSplats:
        """Raw parameters from (possibly trainable, GPU) tensors: detached, on the CPU, float32.

        Shapes as the fields; ``opacity_logits`` may also be ``[N, 1]`` (INRIA's layout).
        """

        def to_np(t: torch.Tensor) -> np.ndarray:
            return t.detach().to(device="cpu", dtype=torch.float32).numpy()

        return cls(to_np(means), to_np(sh), to_np(opacity_logits).reshape(-1), to_np(log_scales), to_np(quats))


# --- writing --------------------------------------------------------------------------


def gaussian_property_names(sh_degree: int) -> list[str]:
    """Vertex property names of the standard layout, in file order, for an SH degree."""
    num_rest = REST_COUNTS[sh_degree]
    return [
        *POSITION_NAMES, *NORMAL_NAMES, *DC_NAMES,
        *(f"{REST_PREFIX}{i}" for i in range(num_rest)),
        OPACITY_NAME, *SCALE_NAMES, *ROT_NAMES,
    ]  # fmt: skip


def _check_metadata(path: Path, metadata: Mapping[str, str]) -> None:
    for key, value in metadata.items():
        if not isinstance(key, str) or not METADATA_KEY_PATTERN.fullmatch(key) or key == FORMAT_KEY:
            raise GaussiansFileError(
                f"{path}: metadata key {key!r} must be letters, digits, '_', '.', '-' and not {FORMAT_KEY!r}"
            )
        if not isinstance(value, str) or not METADATA_VALUE_PATTERN.fullmatch(value):
            raise GaussiansFileError(
                f"{path}: metadata {key!r} must be a one-line printable ASCII string, got {value!r}"
            )


def _check_finite_params(path: Path, splats: GaussianSplats) -> None:
    """Refuse NaN in any parameter (it would make the file unreadable)."""
    for name in ("means", "sh", "opacity_logits", "log_scales", "quats"):
        values = getattr(splats, name)
        bad = np.isnan(values).any(axis=tuple(range(1, values.ndim)))  # [N]
        if bad.any():
            raise GaussiansFileError(
                f"{path}: {name} has NaN for {int(bad.sum())} Gaussian(s), first at index {int(np.argmax(bad))}"
            )


def _pack_records(splats: GaussianSplats) -> np.ndarray:
    """[N, P] float32 rows in the order of :func:`gaussian_property_names`."""
    n, k = splats.sh.shape[:2]
    f_dc = splats.sh[:, 0, :]  # [N, 3]
    f_rest = splats.sh[:, 1:, :].transpose(0, 2, 1).reshape(n, NUM_COLOUR_CHANNELS * (k - 1))  # channel-major
    return np.concatenate(
        [
            splats.means,
            np.zeros((n, len(NORMAL_NAMES)), dtype=np.float32),
            f_dc,
            f_rest,
            splats.opacity_logits[:, None],
            splats.log_scales,
            splats.quats,
        ],
        axis=1,
    ).astype(FLOAT32, copy=False)


def _header(num_vertices: int, names: list[str], metadata: Mapping[str, str]) -> bytes:
    lines = [
        PLY_MAGIC,
        f"format {BINARY_LE} {PLY_VERSION}",
        f"{COMMENT} {METADATA_PREFIX}{FORMAT_KEY} {GAUSSIANS_FORMAT}",
        *(f"{COMMENT} {METADATA_PREFIX}{key} {value}" for key, value in metadata.items()),
        f"element {VERTEX_ELEMENT} {num_vertices}",
        *(f"property float {name}" for name in names),
        END_HEADER,
    ]
    return ("\n".join(lines) + "\n").encode("ascii")


def write_gaussians_ply(
    path: str | os.PathLike, splats: GaussianSplats, metadata: Mapping[str, str] | None = None
) -> None:
    """Write ``splats`` as a binary little-endian 3DGS PLY, atomically.

    The file is written to a temporary file in the same folder, then moved over
    ``path`` with ``os.replace``; a reader never sees a half-written file.

    Args:
        path: destination ``.ply``; its folder must exist.
        splats: raw parameters; NaN anywhere is refused (GaussiansFileError).
        metadata: extra ``comment glimpse-<key> <value>`` header lines, in order; keys are
            one token (letters, digits, ``_ . -``, not ``format``), values one line of
            printable ASCII.
    """
    path = Path(path)
    metadata = dict(metadata or {})
    _check_metadata(path, metadata)
    _check_finite_params(path, splats)
    _check_sh_degree_metadata(path, metadata, splats.sh_degree)
    names = gaussian_property_names(splats.sh_degree)
    header, records = _header(len(splats), names, metadata), _pack_records(splats)
    with staged_file(path) as tmp, tmp.open("xb") as f:
        f.write(header)
        f.write(records.reshape(-1).view(np.uint8))  # buffer protocol, no copy


# --- reading --------------------------------------------------------------------------


@dataclass(frozen=True)
class _Element:
    name: str
    count: int
    properties: list[tuple[str, str]]  # (name, numpy scalar code); code "list" for list properties


@dataclass(frozen=True)
class _Header:
    encoding: str
    elements: list[_Element]
    comments: list[str]
    data_offset: int  # bytes


def _parse_header(path: Path, raw: bytes) -> _Header:
    """Parse the ASCII header at the start of ``raw``."""
    if not raw.startswith(PLY_MAGIC.encode("ascii")):
        raise GaussiansFileError(f"{path}: not a PLY file (does not start with 'ply')")
    match = re.search(rb"^end_header[ \t]*\r?\n", raw, flags=re.MULTILINE)
    if match is None:
        raise GaussiansFileError(f"{path}: PLY header has no 'end_header' line (truncated or not a PLY file)")
    text = raw[: match.start()].decode("ascii", errors="replace")
    encoding, elements, comments = None, [], []
    for line_no, line in enumerate(text.splitlines()[1:], start=2):
        tokens = line.split()
        if not tokens or tokens[0] == "obj_info":
            continue
        keyword = tokens[0]
        if keyword == COMMENT:
            comments.append(line.rstrip("\r")[len(COMMENT) + 1 :])
        elif keyword == "format" and len(tokens) == 3:
            encoding = tokens[1]
            if encoding not in (ASCII, BINARY_LE, BINARY_BE):
                raise GaussiansFileError(f"{path}: unknown PLY format {encoding!r} (line {line_no})")
        elif keyword == "element" and len(tokens) == 3 and tokens[2].isdigit():
            elements.append(_Element(tokens[1], int(tokens[2]), []))
        elif keyword == "property" and elements and len(tokens) == 3 and tokens[1] in PLY_SCALAR_TYPES:
            elements[-1].properties.append((tokens[2], PLY_SCALAR_TYPES[tokens[1]]))
        elif keyword == "property" and elements and len(tokens) == 5 and tokens[1] == "list":
            elements[-1].properties.append((tokens[4], "list"))
        else:
            raise GaussiansFileError(f"{path}: malformed PLY header line {line_no}: {line!r}")
    if encoding is None:
        raise GaussiansFileError(f"{path}: PLY header has no 'format' line")
    return _Header(encoding, elements, comments, match.end())


def _read_metadata(path: Path, comments: list[str]) -> dict[str, str]:
    """``glimpse-<key> <value>`` comments as a dict (without the format key); refuses a
    glimpse-format other than GAUSSIANS_FORMAT."""
    metadata: dict[str, str] = {}
    for comment in comments:
        if not comment.startswith(METADATA_PREFIX):
            continue
        key, _, value = comment[len(METADATA_PREFIX) :].partition(" ")
        if key == FORMAT_KEY:
            found = value.strip()
            if found.startswith(FORMAT_FAMILY) and found != GAUSSIANS_FORMAT:
                raise GaussiansFileError(
                    f"{path}: unknown version {found!r} of the Gaussians format "
                    f"(this reader knows {GAUSSIANS_FORMAT} only)"
                )
            if found != GAUSSIANS_FORMAT:
                raise GaussiansFileError(f"{path}: glimpse-format is {found!r}, not {GAUSSIANS_FORMAT}")
            continue
        if key in metadata:
            raise GaussiansFileError(f"{path}: metadata key {key!r} appears twice in the header")
        metadata[key] = value
    return metadata


def _read_vertex_table(path: Path, raw: bytes, header: _Header) -> tuple[_Element, np.ndarray]:
    """The vertex element's records as a structured array (fields as in the file)."""
    offset_bytes, offset_lines = header.data_offset, 0
    byte_order = ">" if header.encoding == BINARY_BE else "<"
    for element in header.elements:
        has_lists = any(code == "list" for _, code in element.properties)
        if element.name == VERTEX_ELEMENT:
            if has_lists:
                raise GaussiansFileError(f"{path}: vertex element has a list property, not a 3DGS Gaussians file")
            names = [name for name, _ in element.properties]
            duplicates = sorted({n for n in names if names.count(n) > 1})
            if duplicates:
                raise GaussiansFileError(f"{path}: vertex properties appear more than once: {duplicates}")
            dtype = np.dtype([(name, byte_order + code) for name, code in element.properties])
            if header.encoding == ASCII:
                return element, _read_ascii_records(path, raw[header.data_offset :], offset_lines, element, dtype)
            return element, _read_binary_records(path, raw, offset_bytes, element, dtype)
        if header.encoding != ASCII and has_lists:
            raise GaussiansFileError(
                f"{path}: element {element.name!r} with list properties precedes 'vertex' (unsupported)"
            )
        row_bytes = sum(np.dtype(code).itemsize for _, code in element.properties)
        offset_bytes += element.count * row_bytes
        offset_lines += element.count
    raise GaussiansFileError(f"{path}: no 'element vertex' in the PLY header")


def _read_binary_records(path: Path, raw: bytes, offset: int, element: _Element, dtype: np.dtype) -> np.ndarray:
    needed = element.count * dtype.itemsize
    available = max(len(raw) - offset, 0)
    if available < needed:
        raise GaussiansFileError(
            f"{path}: truncated: {element.count} vertices of {dtype.itemsize} bytes need {needed} bytes, "
            f"found {available}"
        )
    return np.frombuffer(raw, dtype=dtype, count=element.count, offset=offset)


def _read_ascii_records(path: Path, body: bytes, skip_lines: int, element: _Element, dtype: np.dtype) -> np.ndarray:
    lines = body.decode("ascii", errors="replace").splitlines()[skip_lines : skip_lines + element.count]
    if len(lines) < element.count:
        raise GaussiansFileError(
            f"{path}: truncated: header declares {element.count} vertices, found {len(lines)} lines"
        )
    table = np.empty(element.count, dtype=dtype)
    num_props = len(element.properties)
    for i, line in enumerate(lines):
        tokens = line.split()
        if len(tokens) != num_props:
            raise GaussiansFileError(f"{path}: vertex {i} has {len(tokens)} values, expected {num_props}")
        try:
            table[i] = tuple(float(token) for token in tokens)
        except (ValueError, OverflowError) as err:
            raise GaussiansFileError(f"{path}: vertex {i}: unreadable number ({err})") from err
    return table


def _rest_names(path: Path, names: list[str]) -> list[str]:
    """The f_rest_* properties sorted by index; their count must be 0, 9, 24 or 45, indices 0..M-1."""
    rest = [n for n in names if n.startswith(REST_PREFIX)]
    if len(rest) not in REST_COUNTS:
        raise GaussiansFileError(
            f"{path}: {len(rest)} f_rest_* properties; expected one of {list(REST_COUNTS)} "
            f"(SH degree 0-{MAX_SH_DEGREE})"
        )
    expected = [f"{REST_PREFIX}{i}" for i in range(len(rest))]
    if sorted(rest, key=lambda n: (len(n), n)) != expected:
        raise GaussiansFileError(f"{path}: f_rest_* properties must be numbered 0..{len(rest) - 1}, found {rest}")
    return expected


def _column_stack(table: np.ndarray, names: list[str] | tuple[str, ...]) -> np.ndarray:
    """[N, len(names)] float32 from structured-array fields."""
    out = np.empty((len(table), len(names)), dtype=np.float32)
    for j, name in enumerate(names):
        out[:, j] = table[name]
    return out


def _check_sh_degree_metadata(path: Path, metadata: Mapping[str, str], sh_degree: int) -> None:
    if SH_DEGREE_KEY in metadata and metadata[SH_DEGREE_KEY] != str(sh_degree):
        raise GaussiansFileError(
            f"{path}: metadata {SH_DEGREE_KEY}={metadata[SH_DEGREE_KEY]!r} "
            f"but the SH coefficients are of degree {sh_degree}"
        )


def read_gaussians_ply(path: str | os.PathLike) -> tuple[GaussianSplats, dict[str, str]]:
    """Read a 3DGS Gaussians PLY (Glimpse's, INRIA's, gsplat's or another exporter's).

    Returns:
        (splats, metadata): the raw parameters as float32 (bit-identical to a float32
        file) and the ``comment glimpse-<key> <value>`` lines other than the format,
        as ``{key: value}``.

    Raises:
        GaussiansFileError: not a PLY, a ``glimpse-format`` other than
            ``glimpse-gaussians/1``, a missing property, an f_rest count other than
            0/9/24/45, truncated data, or NaN in a parameter; the message names the file.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise GaussiansFileError(f"{path}: cannot read Gaussians PLY ({err.strerror or err})") from err
    header = _parse_header(path, raw)
    metadata = _read_metadata(path, header.comments)
    element, table = _read_vertex_table(path, raw, header)
    names = [name for name, _ in element.properties]
    required = [*POSITION_NAMES, *DC_NAMES, OPACITY_NAME, *SCALE_NAMES, *ROT_NAMES]
    missing = [n for n in required if n not in names]
    if missing:
        raise GaussiansFileError(f"{path}: vertex element lacks 3DGS properties {missing}")
    rest_names = _rest_names(path, names)
    n = element.count
    num_rest_coeffs = len(rest_names) // NUM_COLOUR_CHANNELS
    f_rest = _column_stack(table, rest_names).reshape(n, NUM_COLOUR_CHANNELS, num_rest_coeffs)  # channel-major
    sh = np.concatenate([_column_stack(table, DC_NAMES)[:, None, :], f_rest.transpose(0, 2, 1)], axis=1)
    splats = GaussianSplats(
        means=_column_stack(table, POSITION_NAMES),
        sh=sh,
        opacity_logits=_column_stack(table, (OPACITY_NAME,))[:, 0],
        log_scales=_column_stack(table, SCALE_NAMES),
        quats=_column_stack(table, ROT_NAMES),
    )
    _check_finite_params(path, splats)
    _check_sh_degree_metadata(path, metadata, splats.sh_degree)
    return splats, metadata
