"""OpenEXR images of named float channels (render passes for compositing: colour, alpha, depth, masks), through
the OpenEXR package (the Academy Software Foundation's, BSD-3-Clause).

Colours are written linear (the sRGB transfer curve undone), as compositors expect of EXR; alpha is not
premultiplied into them (the render's colour already holds only what was drawn, on black)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from glimpse.io.staging import staged_file

RGB_CHANNELS = ("R", "G", "B")


def srgb_to_linear(values: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] -> linear light (IEC 61966-2-1)."""
    values = np.clip(values, 0.0, 1.0)
    return np.where(values <= 0.04045, values / 12.92, ((values + 0.055) / 1.055) ** 2.4)


def write_exr(path: str | Path, channels: dict[str, np.ndarray], attributes: dict[str, str] | None = None) -> None:
    """Write ``channels`` (name -> [H, W] array, all one size) as 32-bit float channels, ZIP-compressed, with
    string ``attributes`` in the header; atomically (a temporary file, then a rename)."""
    import OpenEXR

    shapes = {np.shape(v) for v in channels.values()}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ValueError(f"EXR channels must be [H, W] arrays of one size, found {sorted(shapes)}")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, **(attributes or {})}
    pixels = {name: np.ascontiguousarray(values, dtype=np.float32) for name, values in channels.items()}
    with staged_file(Path(path)) as tmp, OpenEXR.File(header, pixels) as image:
        image.write(str(tmp))


def read_exr(path: str | Path) -> tuple[dict[str, np.ndarray], dict]:
    """(channel name -> [H, W] float array, header) of an EXR file."""
    import OpenEXR

    with OpenEXR.File(str(path), separate_channels=True) as image:
        return ({name: np.array(channel.pixels) for name, channel in image.channels().items()},
                dict(image.header()))
