"""Image and frame-name helpers.

Images are decoded with Pillow, always fully (``Image.load()``), so a truncated
or corrupt file raises :class:`ImageReadError` here instead of yielding a
half-grey picture later.  Arrays follow the usual convention: ``(H, W)`` or
``(H, W, C)``, ``uint8``, rows top to bottom.
"""

from __future__ import annotations

import io
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from PIL import Image, UnidentifiedImageError

from glimpse.io.staging import staged_file

if TYPE_CHECKING:  # reading and checking images (every make step) does not import torch
    import torch

__all__ = [
    "ImageInfo",
    "ImageReadError",
    "decode_image",
    "frame_name",
    "parse_frame_name",
    "probe_image",
    "read_image_header",
    "read_mask",
    "read_rgb",
    "write_png",
]

FRAME_ID_DIGITS = 6
FRAME_ID_MAX = 10**FRAME_ID_DIGITS - 1
# zlib level of every PNG written (lossless at any level): 1 encodes a 320x240 frame in 10 ms against 15 ms at
# Pillow's default 6, for a file 6% larger; a run writes thousands (frames, masks, crops, renders)
PNG_COMPRESS_LEVEL = 1
_FRAME_NAME = re.compile(r"[0-9]{6}")
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: PNG colour types whose IHDR bit depth is the depth of one sample.
#: (Type 3, palette, stores indices; its palette entries are always 8-bit.)
_PNG_DIRECT_COLOUR_TYPES = {0, 2, 4, 6}
#: Bit depth of one sample for Pillow modes, when the file header does not say.
_MODE_BITS = {"1": 1, "L": 8, "LA": 8, "P": 8, "PA": 8, "RGB": 8, "RGBA": 8,
              "CMYK": 8, "YCbCr": 8, "LAB": 8, "HSV": 8, "I;16": 16, "I;16B": 16,
              "I;16L": 16, "I": 32, "F": 32}


class ImageReadError(ValueError):
    """An image file that cannot be opened or fully decoded."""


@dataclass(frozen=True)
class ImageInfo:
    """What an image file holds, as found by decoding it completely.

    format:    Pillow's format name (``"PNG"``, ``"JPEG"``, ``"MPO"``...), or None.
    mode:      Pillow mode (``"L"``, ``"RGB"``, ``"RGBA"``, ``"1"``, ``"I;16"``...).
    width:     pixels.
    height:    pixels.
    bit_depth: bits per sample as stored in the file (PNG: from the IHDR chunk,
               so a 16-bit RGB PNG reports 16 although Pillow hands out 8-bit RGB;
               palette PNGs report 8, the depth of their palette entries).
    """

    format: str | None
    mode: str
    width: int
    height: int
    bit_depth: int

    @property
    def size_text(self) -> str:
        """``"WxH"``, as used in messages."""
        return f"{self.width}x{self.height}"


def _png_bit_depth(data: bytes) -> int | None:
    """Sample bit depth from a PNG's IHDR chunk, or None when ``data`` is no PNG."""
    if len(data) < 26 or not data.startswith(_PNG_SIGNATURE) or data[12:16] != b"IHDR":
        return None
    depth, colour_type = data[24], data[25]
    return depth if colour_type in _PNG_DIRECT_COLOUR_TYPES else 8


def decode_image(path: str | Path) -> tuple[ImageInfo, Image.Image]:
    """Read and fully decode an image file.

    Returns its :class:`ImageInfo` and the decoded Pillow image (pixels loaded).
    Raises :class:`ImageReadError` for a missing, unreadable, truncated or
    otherwise corrupt file; the message says what went wrong.
    """
    try:
        data = Path(path).read_bytes()
    except OSError as err:
        raise ImageReadError(f"cannot read the file ({err.strerror or err})") from err
    try:
        image = Image.open(io.BytesIO(data))
        image.load()
    except UnidentifiedImageError as err:
        raise ImageReadError("not an image file that Pillow recognises") from err
    except Exception as err:  # Pillow raises OSError, SyntaxError, ValueError, ...
        raise ImageReadError(f"cannot decode the image ({err})") from err
    return _image_info(image, data), image


def _image_info(image: Image.Image, head: bytes) -> ImageInfo:
    """What ``image`` (opened by Pillow) holds; ``head``: the file's first bytes (26 suffice), whose PNG header
    gives the sample bit depth Pillow does not report."""
    depth = _png_bit_depth(head)
    return ImageInfo(image.format, image.mode, image.width, image.height,
                     _MODE_BITS.get(image.mode, 8) if depth is None else depth)


def read_image_header(path: str | Path) -> ImageInfo:
    """An image's format, mode, size and bit depth from its header alone, without decoding its pixels (for a
    file already checked by ``decode_image``). Raises :class:`ImageReadError` when the header does not parse."""
    try:
        with open(path, "rb") as file:
            head = file.read(26)
            file.seek(0)
            with Image.open(file) as image:
                info = _image_info(image, head)
    except OSError as err:
        raise ImageReadError(f"cannot read the image's header ({err.strerror or err})") from err
    except Exception as err:  # Pillow raises UnidentifiedImageError, SyntaxError, ValueError, ...
        raise ImageReadError(f"cannot read the image's header ({err})") from err
    return info


def probe_image(path: str | Path) -> ImageInfo:
    """Decode ``path`` completely and return its format, mode, size and bit depth."""
    return decode_image(path)[0]


def read_rgb(path: str | Path) -> np.ndarray:
    """Read an 8-bit image as RGB: ``(H, W, 3) uint8``.

    Grey, palette and bilevel images are expanded to three channels; an alpha
    channel is dropped (not composited).
    """
    _, image = decode_image(path)
    if image.mode != "RGB":
        image = image.convert("RGB")
    return np.asarray(image, dtype=np.uint8).copy()


def read_mask(path: str | Path) -> np.ndarray:
    """Read a mask PNG as ``(H, W) bool``: 255 (any value >= 128) is True.

    Valid masks hold only 0 and 255; the threshold only matters for masks that
    were never validated.  Bilevel (mode ``"1"``) masks are read as 0/255.
    """
    _, image = decode_image(path)
    if image.mode != "L":
        image = image.convert("L")
    return np.asarray(image, dtype=np.uint8) >= 128


def rgb_to_uint8(rgb: torch.Tensor | np.ndarray) -> np.ndarray:
    """[H, W, 3] float colours in [0, 1] (clamped; a tensor or an array) -> [H, W, 3] uint8, rounded."""
    values = rgb.detach().cpu().numpy() if hasattr(rgb, "detach") else np.asarray(rgb)
    return (np.clip(values, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def write_png(path: str | Path, array: np.ndarray) -> None:
    """Write ``array`` as a PNG, atomically (a temporary file, then a rename).

    array: ``(H, W)`` or ``(H, W, 3)`` or ``(H, W, 4)`` ``uint8``; a ``(H, W)`` bool
    array is written as a 0/255 mask.  Missing parent folders are created.
    """
    array = np.asarray(array)
    if array.dtype == np.bool_ and array.ndim == 2:
        array = array.astype(np.uint8) * 255
    if array.dtype != np.uint8:
        raise ValueError(f"write_png needs uint8 (or 2D bool) pixels; got {array.dtype}")
    if not (array.ndim == 2 or (array.ndim == 3 and array.shape[2] in (3, 4))):
        raise ValueError(f"write_png needs an (H, W), (H, W, 3) or (H, W, 4) array; got {array.shape}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with staged_file(path) as tmp, tmp.open("xb") as handle:
        Image.fromarray(np.ascontiguousarray(array)).save(handle, format="PNG", compress_level=PNG_COMPRESS_LEVEL)


def frame_name(frame_id: int) -> str:
    """The file stem of a frame id: ``42 -> "000042"``."""
    if isinstance(frame_id, bool) or not isinstance(frame_id, (int, np.integer)):
        raise TypeError(f"a frame id is an integer; got {frame_id!r}")
    if not 0 <= frame_id <= FRAME_ID_MAX:
        raise ValueError(f"a frame id must be in 0..{FRAME_ID_MAX}; got {frame_id}")
    return f"{int(frame_id):06d}"


def parse_frame_name(stem: str) -> int | None:
    """The frame id of a file stem of exactly six ASCII digits (``"000042" -> 42``), else None."""
    if _FRAME_NAME.fullmatch(stem) is None:
        return None
    return int(stem)


def frame_files(folder: str | Path) -> dict[int, Path]:
    """Frame id -> file of a folder of frames named by id (stage 01's ``frames/``); other files are skipped."""
    return {fid: p for p in Path(folder).iterdir() if (fid := parse_frame_name(p.stem)) is not None}
