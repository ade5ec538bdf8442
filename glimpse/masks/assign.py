"""One frame's masks from its body layers (pure functions on arrays; lengths in pixels).

Body mode, people taken nearest first (pelvis depth, as GTU):
  region_p  = the pixels where p's body is nearest, grown by ``dilate_px[p]`` (hair, loose
              clothes), minus pixels where a nearer person's body is or that a nearer person took;
  visible_p = region_p minus static scene next to or in front of p (static_near[p], when known:
              background in the band, an occluder over the body).
Provided mode: visible_p is given (the scene's masks).
Both: hidden_p = p's full projection where another person is visible (body mode: a nearer one),
or where static scene is in front (the interior, eroded by ``erode_px[p]``, where static scene
shows (body mode) or no person is visible (provided mode), grown inside the body by ``reach_px[p]``
through such pixels); occluder_p = hidden_p grown by ``occluder_px[p]``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from glimpse.masks.layers import BodyLayers
from glimpse.morphology import disk


@dataclass(frozen=True)
class FrameMasks:
    """visible, occluders [N, H, W] bool per body; order: body indices nearest first."""

    visible: np.ndarray
    occluders: np.ndarray
    order: list[int]


def grow_within(seed: np.ndarray, within: np.ndarray, steps_px: float) -> np.ndarray:
    """seed [H, W] bool grown one pixel (4-neighbours) at a time, ``steps_px`` times (rounded), never
    leaving ``within`` [H, W] bool: the pixels of ``within`` at most that far from the seed along paths
    inside ``within`` (a bounded morphological reconstruction), plus the seed."""
    kernel = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
    grown = seed.astype(np.uint8)
    allowed = (within | seed).astype(np.uint8)
    for _ in range(int(round(steps_px))):
        step = cv2.dilate(grown, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0) & allowed
        if np.array_equal(step, grown):
            break
        grown = step
    return grown.astype(bool)


def static_in_front(full: np.ndarray, candidate: np.ndarray, erode_px: float, reach_px: float) -> np.ndarray:
    """[H, W] bool: where static scene is in front of a body whose projection is ``full``: the ``candidate``
    pixels (static scene shows there) inside the body's interior (eroded by ``erode_px``), grown by
    ``reach_px`` along candidate pixels of the body (thin parts the erosion drops, feet)."""
    return grow_within(disk(full, erode_px, grow=False) & candidate, full & candidate, reach_px)


# refine(body index, region [H, W], sure [H, W], forbidden [H, W]) -> refined region [H, W]
Refiner = Callable[[int, np.ndarray, np.ndarray, np.ndarray], np.ndarray]


def body_frame_masks(layers: BodyLayers, dilate_px: np.ndarray, occluder_px: np.ndarray,
                     static_in_front: np.ndarray | None, static_near: np.ndarray | None,
                     refine: Refiner | None = None) -> FrameMasks:
    """Visible and occluder masks from the bodies alone, plus, when given, [N, H, W] bool pixels
    where static scene is evidently in front of each body, and where static scene shows next to or
    over each body (glimpse.masks.static). ``refine`` may reshape each region (snapping it to image
    edges) keeping ``sure`` pixels and never taking ``forbidden`` ones."""
    order = [int(k) for k in np.argsort(layers.pelvis_depth, kind="stable")]
    taken = np.zeros(layers.owner.shape, bool)
    visible = np.zeros(layers.full.shape, bool)
    for rank, p in enumerate(order):
        nearer_bodies = np.isin(layers.owner, order[:rank])
        forbidden = nearer_bodies | taken
        if static_near is not None:
            forbidden = forbidden | static_near[p]
        region = disk(layers.owner == p, dilate_px[p]) & ~forbidden
        if refine is not None:
            sure = disk(layers.owner == p, 1.0, grow=False) & ~forbidden
            region = refine(p, region, sure, forbidden) & ~forbidden
        visible[p] = region
        taken |= region
    return FrameMasks(visible, _occluders(layers, visible, order, occluder_px, static_in_front, True), order)


def provided_frame_masks(layers: BodyLayers, visible: np.ndarray, erode_px: np.ndarray, reach_px: np.ndarray,
                         occluder_px: np.ndarray) -> FrameMasks:
    """Occluders for given visible masks [N, H, W]: hidden parts of each projected body (static scene in
    front: its interior, eroded by ``erode_px``, where nobody is visible, and the pixels within ``reach_px``
    of that inside the body where nobody is)."""
    order = [int(k) for k in np.argsort(layers.pelvis_depth, kind="stable")]
    nobody = ~visible.any(0)
    in_front = np.stack([static_in_front(full, nobody, erode_px[p], reach_px[p])
                         for p, full in enumerate(layers.full)]) if len(visible) else None
    return FrameMasks(visible, _occluders(layers, visible, order, occluder_px, in_front, False), order)


def _occluders(layers: BodyLayers, visible: np.ndarray, order: list[int], occluder_px: np.ndarray,
               static_in_front: np.ndarray | None, nearer_only: bool) -> np.ndarray:
    occluders = np.zeros(layers.full.shape, bool)
    full = layers.full
    for rank, p in enumerate(order):
        people_in_front = order[:rank] if nearer_only else [q for q in order if q != p]
        hidden = full[p] & visible[people_in_front].any(0)
        if static_in_front is not None:
            hidden |= static_in_front[p] & ~visible[p]
        occluders[p] = disk(hidden, occluder_px[p])
    return occluders


def plate_refiner(layers: BodyLayers, foreground: np.ndarray, known: np.ndarray, band_px: np.ndarray,
                  core_px: np.ndarray, static: np.ndarray | None = None) -> Refiner:
    """A static camera's refinement (glimpse.masks.plate): person p keeps the foreground pixels
    [H, W] nearer (in the image) to its visible body than to any other and at most ``band_px[p]``
    from it, its body's interior (eroded by ``core_px[p]``; colours like the plate's there are the
    person's clothes, unless the pixel is ``static`` over the whole video: scene in front), and its
    grown body where the plate is unknown (``known`` False)."""
    if not len(layers.pelvis_depth):
        return lambda p, region, sure, forbidden: region
    distance = np.stack([cv2.distanceTransform((layers.owner != p).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5)
                         for p in range(len(layers.pelvis_depth))])
    nearest = distance.argmin(0)

    def refine(p: int, region: np.ndarray, sure: np.ndarray, forbidden: np.ndarray) -> np.ndarray:
        reach = (nearest == p) & (distance[p] <= band_px[p])
        core = disk(layers.owner == p, core_px[p], grow=False)
        if static is not None:
            core &= ~static
        return ((foreground & reach) | (region & ~known) | core) & ~forbidden

    return refine
