"""Square crops of one person: the box around its mask, cropping with padding (the box may leave
the frame; what lies outside is "not person"), the soft mask, resizing and compositing over a
random background colour.

Pixels follow OpenCV (CONTRACTS.md): the centre of pixel (u, v) is at (u, v); a box covers whole
pixels, columns x0 .. x0 + side - 1 and rows y0 .. y0 + side - 1 of the frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from glimpse.morphology import disk

COLOUR_LEVELS = 256  # background colours are uniform over the 8-bit RGB cube
SEED_MASK = 0xFFFFFFFF  # the seed enters numpy's SeedSequence as an unsigned 32-bit word
# resizing: shrinking averages areas (no aliasing); enlarging the image is bicubic (sharper), the
# mask bilinear (stays within [0, 1], no ringing)
SHRINK = cv2.INTER_AREA
ENLARGE_IMAGE = cv2.INTER_CUBIC
ENLARGE_MASK = cv2.INTER_LINEAR


@dataclass(frozen=True)
class CropBox:
    """A square of the frame: top-left pixel (x0, y0) (may be negative or past the frame) and side,
    all in frame pixels."""

    x0: int
    y0: int
    side: int

    def to_crop(self, pixels: np.ndarray, size: int) -> np.ndarray:
        """[N, 2] frame pixels (u, v) -> [N, 2] pixels of the crop resized to ``size`` (the mapping
        cv2.resize uses: pixel centres at half-integers of the pixel grid)."""
        origin = np.array([self.x0, self.y0], dtype=np.float64)
        return (np.asarray(pixels, dtype=np.float64) - origin + 0.5) * (size / self.side) - 0.5

    def as_list(self) -> list[int]:
        """[x0, y0, side] as crops.json writes it."""
        return [self.x0, self.y0, self.side]


def square_box(mask: np.ndarray, margin: float) -> CropBox | None:
    """The square centred on the bounding box of ``mask`` [H, W] bool, its side ``margin`` times the
    box's larger side (rounded up, in pixels); None for an empty mask. The square always contains
    the whole bounding box."""
    rows, cols = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
    if not len(rows):
        return None
    x_min, x_max, y_min, y_max = int(cols[0]), int(cols[-1]), int(rows[0]), int(rows[-1])
    side = max(1, math.ceil(margin * max(x_max - x_min + 1, y_max - y_min + 1)))
    # centre in pixel-edge coordinates (pixel k spans [k, k + 1)); flooring keeps the box around it
    centre_x, centre_y = (x_min + x_max + 1) / 2.0, (y_min + y_max + 1) / 2.0
    return CropBox(math.floor(centre_x - side / 2.0), math.floor(centre_y - side / 2.0), side)


def crop_padded(array: np.ndarray, box: CropBox, fill: float | int | bool = 0) -> np.ndarray:
    """array [H, W] or [H, W, C] -> [side, side(, C)] of the box, ``fill`` where it leaves the frame."""
    height, width = array.shape[:2]
    out = np.full((box.side, box.side, *array.shape[2:]), fill, dtype=array.dtype)
    x_a, y_a = max(box.x0, 0), max(box.y0, 0)
    x_b, y_b = min(box.x0 + box.side, width), min(box.y0 + box.side, height)
    if x_a < x_b and y_a < y_b:
        out[y_a - box.y0:y_b - box.y0, x_a - box.x0:x_b - box.x0] = array[y_a:y_b, x_a:x_b]
    return out


def soft_mask(mask: np.ndarray, erode_px: float, feather_px: float) -> np.ndarray:
    """mask [h, w] bool -> [h, w] float32 in [0, 1]: eroded by a disk of ``erode_px`` (rounded),
    then blurred by a Gaussian of standard deviation ``feather_px`` (0 = sharp); both in the mask's
    pixels. Everything beyond the array counts as not person: give the padded crop, which holds the
    whole mask, and the result equals that of the whole frame, cropped."""
    eroded = disk(mask, erode_px, grow=False).astype(np.float32)
    if feather_px <= 0:
        return eroded
    blurred = cv2.GaussianBlur(eroded, (0, 0), sigmaX=feather_px, sigmaY=feather_px, borderType=cv2.BORDER_CONSTANT)
    return np.clip(blurred, 0.0, 1.0)


def background_colour(seed: int, person_index: int, frame_id: int) -> np.ndarray:
    """[3] uint8: one random colour per crop, the same for the same (seed, person, frame)."""
    rng = np.random.default_rng([seed & SEED_MASK, person_index, frame_id])
    return rng.integers(0, COLOUR_LEVELS, size=3).astype(np.uint8)


def composite(image: np.ndarray, alpha: np.ndarray, colour: np.ndarray) -> np.ndarray:
    """image [h, w, 3] uint8 over ``colour`` [3] through alpha [h, w] in [0, 1] -> [h, w, 3] float32 (0-255)."""
    a = alpha[..., None].astype(np.float32)
    return a * image.astype(np.float32) + (1.0 - a) * colour.astype(np.float32)


def resize_square(array: np.ndarray, size: int, is_mask: bool) -> np.ndarray:
    """[side, side(, C)] float32 -> [size, size(, C)] float32: area averaging when shrinking, bicubic
    (image) or bilinear (mask) when enlarging; the mask is clipped to [0, 1], the image to 0-255."""
    side = array.shape[0]
    if side == size:
        out = array.copy()
    else:
        interpolation = SHRINK if side > size else (ENLARGE_MASK if is_mask else ENLARGE_IMAGE)
        out = cv2.resize(array, (size, size), interpolation=interpolation)
    return np.clip(out, 0.0, 1.0 if is_mask else COLOUR_LEVELS - 1.0)


def to_uint8(array: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """float array times ``scale`` -> uint8, rounded (image 0-255: scale 1; mask 0-1: scale 255)."""
    return np.clip(np.rint(array * scale), 0, COLOUR_LEVELS - 1).astype(np.uint8)
