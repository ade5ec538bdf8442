"""Where the people are in each input frame, so that stage 01 ignores them.

Moving people break the static-scene assumption of structure from motion
(DESIGN.md: unmasked, a walking person gave camera errors of 0.3-1.8 m on a
synthetic room; masked, under 1 mm). Per person and frame the scene's visible
mask is used, else a box around the confident 2D keypoints; both are dilated.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from glimpse.cameras.undistort import Undistorter
from glimpse.io.images import read_mask
from glimpse.scene import Scene, read_keypoints2d


@dataclass(frozen=True)
class PersonRegions:
    """masks: frame id -> (H, W) bool, True on (dilated) people; sources: which cues were used."""

    masks: dict[int, np.ndarray]
    sources: tuple[str, ...]  # subset of ("masks", "keypoint boxes"); empty: nothing known about people

    def exclusion(self, frame_id: int, shape: tuple[int, int]) -> np.ndarray:
        return self.masks.get(frame_id, np.zeros(shape, dtype=bool))


def keypoint_box(xy: np.ndarray, margin: float, width: int, height: int) -> tuple[int, int, int, int] | None:
    """(N, 2) confident keypoints -> (x0, y0, x1, y1) box grown by ``margin`` x its size, clipped."""
    if len(xy) < 2:
        return None
    lo, hi = xy.min(0), xy.max(0)
    pad = margin * (hi - lo)
    x0, y0 = np.floor(lo - pad).astype(int)
    x1, y1 = np.ceil(hi + pad).astype(int)
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, width - 1), min(y1, height - 1)
    if x1 < x0 or y1 < y0:
        return None  # entirely outside the image
    return int(x0), int(y0), int(x1), int(y1)


def find_person_regions(
    scene: Scene, frame_ids: list[int], undistorter: Undistorter,
    dilate_fraction: float, min_confidence: float, box_margin: float,
) -> PersonRegions:
    """People in each of ``frame_ids`` (undistorted pixels), dilated by ``dilate_fraction`` of the diagonal."""
    width, height = scene.width, scene.height
    wanted = set(frame_ids)
    masks: dict[int, np.ndarray] = {}
    sources: set[str] = set()
    for person in scene.humans.values():
        covered: set[int] = set()
        for fid, path in person.masks.items():
            if fid in wanted:
                masks.setdefault(fid, np.zeros((height, width), bool))
                masks[fid] |= undistorter.mask(read_mask(path))
                covered.add(fid)
                sources.add("masks")
        if person.keypoints2d is None:
            continue
        kp = read_keypoints2d(person.keypoints2d)
        for fid, points in zip(kp.frame_ids.tolist(), kp.keypoints):
            if fid not in wanted or fid in covered:
                continue
            xy = undistorter.points(points[points[:, 2] >= min_confidence, :2])
            box = keypoint_box(xy, box_margin, width, height)
            if box is None:
                continue
            x0, y0, x1, y1 = box
            masks.setdefault(fid, np.zeros((height, width), bool))[y0 : y1 + 1, x0 : x1 + 1] = True
            sources.add("keypoint boxes")
    radius = int(round(dilate_fraction * float(np.hypot(width, height))))
    if radius > 0:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        masks = {fid: cv2.dilate(m.astype(np.uint8), kernel).astype(bool) for fid, m in masks.items()}
    return PersonRegions(masks=masks, sources=tuple(sorted(sources)))
