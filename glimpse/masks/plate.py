"""A static camera's background plate, and the foreground it reveals.

The plate is, per pixel, the median colour over the frames in which no person's projected body
(grown by a margin) covers the pixel: people move, so most pixels are uncovered in most frames.
Where bodies cover a pixel in every frame the plate is unknown. A frame's foreground is where
its colour differs from the plate by more than a threshold (largest channel difference).

Limits: a person who never moves leaves the plate unknown where they stand (stage 03 then uses
the body there); people coloured like the wall behind them leave holes (the body's interior is
always kept); shadows and reflections count as foreground; lighting changes over the video break
the plate. A moving camera has no plate.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

ROW_BLOCK = 64  # rows per block of the median, bounding memory to frames x 64 x width x 3 floats


@dataclass(frozen=True)
class Plate:
    """colour [H, W, 3] in [0, 1]; known [H, W] bool (some frame shows the pixel without a body)."""

    colour: np.ndarray
    known: np.ndarray

    def foreground(self, image: np.ndarray, threshold: float) -> np.ndarray:
        """[H, W] bool: known pixels whose colour (image [H, W, 3] uint8) differs from the plate."""
        difference = np.abs(image / 255.0 - self.colour).max(-1)
        return self.known & (difference > threshold)


def median_plate(frames: list[np.ndarray], covered: list[np.ndarray]) -> Plate:
    """frames [H, W, 3] uint8 and covered [H, W] bool (bodies there) -> the plate (median over the
    uncovered samples of each pixel)."""
    stack = np.stack(frames)
    hidden = np.stack(covered)
    height, width = hidden.shape[1:]
    colour = np.zeros((height, width, 3))
    for top in range(0, height, ROW_BLOCK):
        rows = slice(top, top + ROW_BLOCK)
        samples = stack[:, rows].astype(np.float32) / 255.0
        samples[hidden[:, rows]] = np.nan
        with warnings.catch_warnings():  # pixels covered in every frame: an expected all-NaN median
            warnings.simplefilter("ignore", RuntimeWarning)
            colour[rows] = np.nanmedian(samples, axis=0)
    known = ~hidden.all(0)
    colour[~known] = 0.0
    return Plate(colour, known)

