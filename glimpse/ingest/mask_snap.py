"""Person masks snapped to the frame's edges: each person's mask filtered by a colour guided filter (He, Sun and
Tang, "Guided Image Filtering", ECCV 2010) with the frame as the guide, each pixel then given to the person whose
filtered mask is highest there, if over one half.

The masks come from the landmark model's 256x256 segmentation pasted onto the frame with bilinear resampling: at a
phone video's size their edges are a few pixels soft and off the body's outline. The guided filter's output is, in
every window, a linear function of the frame's colours, so a mask edge within ``radius`` of a colour edge moves onto
it; where the frame is flat (colours varying less than about sqrt(``eps``)) the mask is only smoothed.
"""

from __future__ import annotations

import cv2
import numpy as np

OWNED = 0.5  # a pixel belongs to a person whose filtered mask exceeds this


def box_mean(values: np.ndarray, radius: int) -> np.ndarray:
    """[H, W] float32: the mean over the (2 radius + 1)^2 window around each pixel (the image mirrored at its
    borders, edge pixels repeated: OpenCV's BORDER_REFLECT)."""
    size = 2 * radius + 1
    return cv2.boxFilter(values, -1, (size, size), normalize=True, borderType=cv2.BORDER_REFLECT)


def _inverse_3x3(m: np.ndarray) -> np.ndarray:
    """[..., 3, 3] -> the inverse of each symmetric positive definite matrix (adjugate over determinant)."""
    a, b, c = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    d, e, f = m[..., 1, 1], m[..., 1, 2], m[..., 2, 2]
    adjugate = np.stack([np.stack([d * f - e * e, c * e - b * f, b * e - c * d], -1),
                         np.stack([c * e - b * f, a * f - c * c, b * c - a * e], -1),
                         np.stack([b * e - c * d, b * c - a * e, a * d - b * b], -1)], -2)
    determinant = a * adjugate[..., 0, 0] + b * adjugate[..., 1, 0] + c * adjugate[..., 2, 0]
    return adjugate / determinant[..., None, None]


def guided_filter(guide: np.ndarray, sources: np.ndarray, radius: int, eps: float) -> np.ndarray:
    """[P, H, W] float32: each of ``sources`` [P, H, W] filtered with the colour ``guide`` [H, W, 3] (values in
    [0, 1]) over (2 radius + 1)^2 windows, regularised by ``eps`` (He et al.'s colour guided filter)."""
    guide = guide.astype(np.float32)
    mean_guide = np.stack([box_mean(guide[..., c], radius) for c in range(3)], -1)
    covariance = np.empty(guide.shape[:2] + (3, 3), np.float32)
    for i in range(3):
        for j in range(i, 3):
            covariance[..., i, j] = covariance[..., j, i] = (box_mean(guide[..., i] * guide[..., j], radius)
                                                             - mean_guide[..., i] * mean_guide[..., j])
    inverse = _inverse_3x3(covariance + eps * np.eye(3, dtype=np.float32))
    out = np.empty(sources.shape, np.float32)
    for k, source in enumerate(sources.astype(np.float32)):
        mean_source = box_mean(source, radius)
        cross = np.stack([box_mean(guide[..., c] * source, radius) for c in range(3)], -1)
        slope = np.einsum("hwij,hwj->hwi", inverse, cross - mean_guide * mean_source[..., None])
        offset = mean_source - (slope * mean_guide).sum(-1)
        mean_slope = np.stack([box_mean(np.ascontiguousarray(slope[..., c]), radius) for c in range(3)], -1)
        out[k] = (mean_slope * guide).sum(-1) + box_mean(offset, radius)
    return out


def snapped_masks(frame: np.ndarray, masks: list[np.ndarray], radius: int, eps: float) -> list[np.ndarray]:
    """Each of ``masks`` ([H, W] bool, one per person, disjoint) snapped to ``frame``'s edges ([H, W, 3] uint8 as
    the guide; see the module docstring); a pixel goes to the person whose filtered mask is highest there, if over
    one half. Computed within the box around all the masks grown by 2 radius + 1 pixels. A mask that would vanish
    is kept as it was."""
    if radius < 1 or not masks:
        return masks
    union = np.any(masks, axis=0)
    if not union.any():
        return masks
    rows, cols = np.flatnonzero(union.any(1)), np.flatnonzero(union.any(0))
    margin = 2 * radius + 1
    y0, y1 = max(rows[0] - margin, 0), min(rows[-1] + margin + 1, union.shape[0])
    x0, x1 = max(cols[0] - margin, 0), min(cols[-1] + margin + 1, union.shape[1])
    window = (slice(y0, y1), slice(x0, x1))
    filtered = guided_filter(frame[window].astype(np.float32) / 255.0,
                             np.stack([m[window] for m in masks]).astype(np.float32), radius, eps)
    owner = np.argmax(filtered, 0)
    owned = filtered.max(0) > OWNED
    out = []
    for k, mask in enumerate(masks):
        snapped = np.zeros_like(mask)
        snapped[window] = owned & (owner == k)
        out.append(snapped if snapped.any() else mask)
    return out
