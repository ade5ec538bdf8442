"""Growing and shrinking boolean masks by a disk (the one morphology every stage uses on masks)."""

from __future__ import annotations

import cv2
import numpy as np


def disk(mask: np.ndarray, radius_px: float, grow: bool = True) -> np.ndarray:
    """mask [H, W] bool dilated (grow) or eroded by a disk of ``radius_px`` (rounded; 0 = unchanged;
    at most the mask's larger side, beyond which a disk changes nothing more)."""
    radius = int(round(min(radius_px, max(mask.shape))))
    if radius <= 0:
        return mask.copy()
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    op = cv2.dilate if grow else cv2.erode
    return op(mask.astype(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
