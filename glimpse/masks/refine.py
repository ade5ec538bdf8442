"""Snapping a person's mask to the image's edges: OpenCV GrabCut, seeded by the body.

In a crop around the person: the body's own pixels (eroded) are sure foreground, the grown
silhouette probable foreground, a band around it (``band_px`` wide) probable background, and
everything else, plus pixels another person or the static scene holds, sure background.
GrabCut's colour models then move the boundary to where the colours change: onto hair and
loose clothes the naked body misses, off background the grown silhouette took.
"""

from __future__ import annotations

import cv2
import numpy as np

from glimpse.morphology import disk


def grabcut_region(image: np.ndarray, region: np.ndarray, sure: np.ndarray, forbidden: np.ndarray, band_px: float,
                   iterations: int) -> np.ndarray:
    """image [H, W, 3] uint8 RGB; region, sure, forbidden [H, W] bool -> refined region [H, W] bool."""
    if not sure.any() or iterations <= 0:
        return region
    reach = disk(region, band_px) & ~forbidden
    rows, cols = np.nonzero(disk(reach, band_px))  # context beyond the band for the background model
    top, bottom, left, right = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    crop = (slice(top, bottom), slice(left, right))
    seeds = np.full(region[crop].shape, cv2.GC_BGD, np.uint8)
    seeds[reach[crop]] = cv2.GC_PR_BGD
    seeds[region[crop]] = cv2.GC_PR_FGD
    seeds[sure[crop]] = cv2.GC_FGD
    seeds[forbidden[crop]] = cv2.GC_BGD
    if not (seeds == cv2.GC_BGD).any() and not (seeds == cv2.GC_PR_BGD).any():
        return region
    background, foreground = np.zeros((1, 65)), np.zeros((1, 65))  # OpenCV's GMM state, 5 components
    bgr = np.ascontiguousarray(image[crop][..., ::-1])
    cv2.setRNGSeed(0)
    cv2.grabCut(bgr, seeds, None, background, foreground, iterations, cv2.GC_INIT_WITH_MASK)
    refined = np.zeros_like(region)
    refined[crop] = (seeds == cv2.GC_FGD) | (seeds == cv2.GC_PR_FGD)
    return refined
