"""The fitted bodies drawn over the input frames, to see at a glance whether a fit is right.

Each body's vertices are projected and splatted (2x2 pixels); each pixel shows its nearest
splat, so nearer bodies cover farther ones, tinted with the person's colour and shaded by how squarely the
surface faces the camera, over the frame at OVERLAY_OPACITY. The person's observed confident
2D keypoints are white dots ringed in that colour.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from glimpse.body.normals import vertex_normals
from glimpse.cameras.model import PinholeCamera

PERSON_COLOURS = ((230, 80, 60), (60, 140, 230), (90, 200, 90), (230, 190, 50), (190, 90, 210), (60, 200, 200))
OVERLAY_OPACITY = 0.55
SHADE_FLOOR = 0.35  # a surface seen edge-on keeps this fraction of the colour
SPLAT_OFFSETS = ((0, 0), (0, 1), (1, 0), (1, 1))  # pixel offsets each projected vertex covers
KEYPOINT_RADIUS_PX = 2


@dataclass(frozen=True)
class OverlayBody:
    """vertices [V, 3] world; keypoints [K, 2] pixels with confidence [K] (0 = not drawn); colour RGB."""

    vertices: np.ndarray
    keypoints: np.ndarray | None
    confidence: np.ndarray | None
    colour: tuple[int, int, int]


def overlay_frame(image: np.ndarray, camera: PinholeCamera, faces: np.ndarray, bodies: list[OverlayBody]) -> np.ndarray:
    """image [H, W, 3] uint8 -> a copy with the bodies drawn (see the module docstring)."""
    height, width = image.shape[:2]
    depth_all, pixels_all, colours_all = [], [], []
    for body in bodies:
        cam = body.vertices @ camera.R.T + camera.t
        normals = vertex_normals(body.vertices, faces) @ camera.R.T
        front = cam[:, 2] > 1e-6
        view = -cam / np.maximum(np.linalg.norm(cam, axis=1, keepdims=True), 1e-12)
        shade = SHADE_FLOOR + (1 - SHADE_FLOOR) * np.abs((normals * view).sum(1))
        uv = cam[front, :2] / cam[front, 2:3] * [camera.K[0, 0], camera.K[1, 1]] + camera.K[:2, 2]
        depth_all.append(cam[front, 2])
        pixels_all.append(np.round(uv).astype(np.int64))
        colours_all.append(shade[front, None] * np.asarray(body.colour, float))
    result = np.array(image, dtype=np.uint8, copy=True)
    if depth_all:
        depth, pixels, colours = np.concatenate(depth_all), np.concatenate(pixels_all), np.concatenate(colours_all)
        u = np.concatenate([pixels[:, 0] + du for du, _ in SPLAT_OFFSETS])
        v = np.concatenate([pixels[:, 1] + dv for _, dv in SPLAT_OFFSETS])
        splat_depth, splat_colour = np.tile(depth, len(SPLAT_OFFSETS)), np.tile(colours, (len(SPLAT_OFFSETS), 1))
        inside = (u >= 0) & (u < width) & (v >= 0) & (v < height)
        linear = v[inside] * width + u[inside]
        order = np.lexsort((splat_depth[inside], linear))  # by pixel, nearest first (ties: the earlier splat)
        linear = linear[order]
        first = np.flatnonzero(np.r_[True, linear[1:] != linear[:-1]])  # the nearest splat of each pixel
        hit = linear[first]
        flat = result.reshape(-1, 3)  # only the painted pixels change
        blended = (1 - OVERLAY_OPACITY) * flat[hit].astype(np.float64) + OVERLAY_OPACITY * splat_colour[inside][order[first]]
        flat[hit] = np.clip(np.round(blended), 0, 255).astype(np.uint8)
    for body in bodies:
        if body.keypoints is None:
            continue
        for (x, y), c in zip(body.keypoints, body.confidence):
            if c > 0 and np.isfinite(x) and np.isfinite(y):
                centre = (int(round(x)), int(round(y)))
                cv2.circle(result, centre, KEYPOINT_RADIUS_PX + 1, body.colour, -1, cv2.LINE_AA)
                cv2.circle(result, centre, KEYPOINT_RADIUS_PX, (255, 255, 255), -1, cv2.LINE_AA)
    return result
