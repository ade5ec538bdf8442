"""What a person looks like, for telling people apart: colour histograms of the upper and the lower body.

The person's pixels (segmentation above a threshold) are split at the mid-hip height; each half gives a
hue x saturation histogram (HSV), weighted to unit sum. Two appearances are compared by the Hellinger distance
(0 = the same colours, 1 = nothing in common), averaged over the halves that both have pixels.
"""

from __future__ import annotations

import cv2
import numpy as np

SATURATION_BINS = 3
MIN_PIXELS = 30  # a half with fewer person pixels gives no histogram


def _histogram(hsv: np.ndarray, bins: int) -> np.ndarray | None:
    if len(hsv) < MIN_PIXELS:
        return None
    hue = (hsv[:, 0].astype(int) * bins) // 180
    saturation = (hsv[:, 1].astype(int) * SATURATION_BINS) // 256
    counts = np.bincount(hue * SATURATION_BINS + saturation, minlength=bins * SATURATION_BINS).astype(float)
    return counts / counts.sum()


def appearance(image: np.ndarray, mask: np.ndarray, split_y: float, bins: int) -> np.ndarray:
    """image [H, W, 3] uint8 RGB, mask [H, W] bool, split_y: image row between upper and lower body.
    Returns [2, bins * 3] histograms; a half without enough pixels is all NaN."""
    ys, xs = np.nonzero(mask)
    if len(ys) == 0:
        return np.full((2, bins * SATURATION_BINS), np.nan)
    hsv = cv2.cvtColor(image[ys, xs][None], cv2.COLOR_RGB2HSV)[0]
    halves = []
    for part in (ys < split_y, ys >= split_y):
        hist = _histogram(hsv[part], bins)
        halves.append(np.full(bins * SATURATION_BINS, np.nan) if hist is None else hist)
    return np.stack(halves)


def _shared_halves(a: np.ndarray, b: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The (half of a, half of b) pairs that both appearances have (a missing half is NaN)."""
    return [(half_a, half_b) for half_a, half_b in zip(a, b) if not (np.isnan(half_a).any() or np.isnan(half_b).any())]


def comparable(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two appearances share a half that both have (else their distance says nothing)."""
    return bool(_shared_halves(a, b))


def appearance_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Hellinger distance between two appearances, averaged over the halves both have; 1 when none."""
    distances = [float(np.sqrt(max(0.0, 1.0 - np.sum(np.sqrt(half_a * half_b))))) for half_a, half_b in
                 _shared_halves(a, b)]
    return float(np.mean(distances)) if distances else 1.0


def blend(old: np.ndarray, new: np.ndarray, rate: float) -> np.ndarray:
    """Running appearance: ``old`` moved towards ``new`` by ``rate``, half by half (a missing half keeps the other)."""
    out = old.copy()
    for half in range(len(old)):
        if np.isnan(new[half]).any():
            continue
        out[half] = new[half] if np.isnan(old[half]).any() else (1 - rate) * old[half] + rate * new[half]
    return out
