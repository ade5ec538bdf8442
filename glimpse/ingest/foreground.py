"""Where a fixed camera's frame differs from its background plate and no found person explains it: regions to
look for the people the face-keyed detector misses (seen from behind, entering, half hidden).

Pixels farther than ``foreground_threshold`` from the plate, minus those the people already found explain, are
opened (specks go) and closed (a person's pieces, split where their clothes match the background, join), and
each connected blob is one candidate. A blob wider than ``foreground_person_aspect`` times its height holds
several people side by side (people who walk together merge into one blob): it is looked at whole and cut into
that many person-wide windows. The landmark model, given a crop with two people in it, often finds neither, so
each window is looked at with the rest of the blob painted over by the plate, and every candidate with the
people already found painted over too: the model sees one person. Where the plate cannot paint someone over
(it shows them: they stood still), :func:`surroundings_fill` gives the colour around them.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from glimpse.ingest.config import IngestConfig
from glimpse.ingest.crop import Region

OPEN_KERNEL_PX = 5  # opening that removes specks of noise (pixels, at the tracking size)
FILL_DOWNSCALE = 8  # surroundings_fill computes its colours at 1/8 size
FILL_SIGMA_PX = 48.0  # pixels: the reach of its Gaussian weights (about a torso's width at 1280 px)
FILL_MIN_WEIGHT = 1e-3  # share of outside pixels under which its normalised convolution is not divided further


@dataclass(frozen=True)
class ForegroundCandidate:
    region: Region  # upright square to give the landmark model
    paint: np.ndarray  # [H, W] bool: pixels to replace by the plate before looking (people found, the rest of the blob)


def differs_from_plate(pixels: np.ndarray, plate: np.ndarray, threshold: float) -> np.ndarray:
    """[...] bool: RGB ``pixels`` [..., 3] uint8 farther than ``threshold`` (8-bit levels, any channel) from the
    plate's ``plate`` [..., 3] at the same places."""
    return np.abs(pixels.astype(np.int16) - plate.astype(np.int16)).max(axis=-1) > threshold


def unexplained_foreground(image: np.ndarray, plate: np.ndarray, explained: np.ndarray, config: IngestConfig
                           ) -> np.ndarray:
    """[H, W] uint8 (0/1): pixels that differ from the plate and that no found person explains, cleaned."""
    difference = differs_from_plate(image, plate, config.foreground_threshold) & ~explained
    opened = cv2.morphologyEx(difference.astype(np.uint8), cv2.MORPH_OPEN,
                              cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (OPEN_KERNEL_PX,) * 2))
    close_px = max(1, round(config.foreground_close * image.shape[0])) | 1
    return cv2.morphologyEx(opened, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (close_px,) * 2))


def foreground_candidates(image: np.ndarray, plate: np.ndarray, explained: np.ndarray, config: IngestConfig,
                          person_side: float) -> list[ForegroundCandidate]:
    """Candidate regions (see the module docstring), at least ``person_side`` pixels wide (a blob is often a part
    of a person: the rest is hidden or explained)."""
    foreground = unexplained_foreground(image, plate, explained, config)
    _, labels, stats, _ = cv2.connectedComponentsWithStats(foreground)
    min_area = config.foreground_min_area * image.shape[0] * image.shape[1]
    columns = np.arange(image.shape[1])[None]
    candidates = []
    for label, (x, y, w, h, area) in enumerate(stats):
        if label == 0 or area < min_area:
            continue
        blob = labels == label
        count = max(1, round(w / (config.foreground_person_aspect * h)))
        windows = [(x, x + w)]
        if count > 1:
            windows += [(x + k * w / count, x + (k + 1) * w / count) for k in range(count)]
        for x0, x1 in windows:
            side = max(max(x1 - x0, h) * config.foreground_region_grow, person_side)
            region = Region(np.array([(x0 + x1 - 1) / 2, y + (h - 1) / 2]), side, 0.0)
            candidates.append(ForegroundCandidate(region, explained | (blob & ((columns < x0) | (columns >= x1)))))
    return candidates


def surroundings_fill(image: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """[H, W, 3] uint8: at each pixel the mean colour of the image outside ``pixels`` [H, W] bool nearby, weighted
    by a Gaussian of FILL_SIGMA_PX (normalised convolution at 1/FILL_DOWNSCALE size). Covers people with something
    that has no person's edges or texture."""
    height, width = pixels.shape
    small = (max(1, width // FILL_DOWNSCALE), max(1, height // FILL_DOWNSCALE))
    outside = ~pixels
    weight = cv2.resize(outside.astype(np.float32), small, interpolation=cv2.INTER_AREA)
    colour = cv2.resize(image.astype(np.float32) * outside[..., None], small, interpolation=cv2.INTER_AREA)
    sigma = FILL_SIGMA_PX / FILL_DOWNSCALE
    weight = cv2.GaussianBlur(weight, (0, 0), sigma)
    colour = cv2.GaussianBlur(colour, (0, 0), sigma)
    fill = colour / np.maximum(weight, FILL_MIN_WEIGHT)[..., None]
    return np.clip(cv2.resize(fill, (width, height), interpolation=cv2.INTER_LINEAR), 0, 255).astype(np.uint8)


def beside_fill(source: np.ndarray, pixels: np.ndarray, margin: int, blocked: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """([H, W, 3] uint8 fill, [H, W] bool where it is given): each connected region of ``pixels`` [H, W] bool takes
    ``source``'s pixels (the background plate) one region's width plus ``margin`` pixels to its left or right, from the
    side with more of them inside the frame and off ``blocked`` [H, W] bool (default: ``pixels``), then from the other
    side where that one has none. Covers a person the plate shows (they stood still) with the background's own
    texture from beside them: a flat patch of their surroundings' colour, person-shaped, is itself taken for a body
    by the landmark model."""
    width = pixels.shape[1]
    blocked = pixels if blocked is None else blocked
    fill, given = np.zeros_like(source), np.zeros_like(pixels)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(pixels.astype(np.uint8))
    for label in range(1, count):
        ys, xs = np.nonzero(labels == label)
        shift = int(stats[label, cv2.CC_STAT_WIDTH]) + margin
        sources = [xs - shift, xs + shift]
        valid = [(x >= 0) & (x < width) & ~blocked[ys, np.clip(x, 0, width - 1)] for x in sources]
        # the side with more pixels last: it overwrites where both have one (a tie: the left side)
        for side in sorted((1, 0), key=lambda side: int(valid[side].sum())):
            ok = valid[side]
            fill[ys[ok], xs[ok]] = source[ys[ok], sources[side][ok]]
            given[ys[ok], xs[ok]] = True
    return fill, given
