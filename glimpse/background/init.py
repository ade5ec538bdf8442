"""Where the background Gaussians start: stage 01's SfM points, or a textured sphere.

Sphere (static camera; GTU's choice): points on a sphere of radius R around the people's
mean position, where the input cameras see it: each distinct camera casts rays through a
pixel grid (``spacing_px`` apart, a margin beyond the borders) onto the sphere. Each point
takes the median colour of the background pixels it projects to over the frames; points
no frame shows on a background pixel (always behind people) take the colour of the
nearest point that was seen, and are flagged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from glimpse.cameras.model import PinholeCamera
from glimpse.errors import GlimpseError

GRID_MARGIN_CELLS = 4  # the ray grid reaches this many cells beyond each image border
GREY = 0.5  # colour of points when no frame shows any of them
POSE_TOLERANCE = 1e-9  # cameras whose R and t differ by less than this cast one set of rays


@dataclass
class InitialCloud:
    """points [N, 3] world units; rgb [N, 3] in [0, 1]; seen [N] bool (a frame showed the point on a
    background pixel; always True for SfM points, which were triangulated from the frames)."""

    points: np.ndarray
    rgb: np.ndarray
    seen: np.ndarray


@dataclass(frozen=True)
class Sphere:
    centre: np.ndarray  # [3] world units
    radius: float  # world units


def distinct_cameras(cameras: list[PinholeCamera]) -> list[PinholeCamera]:
    kept: list[PinholeCamera] = []
    for cam in cameras:
        if not any(np.abs(cam.R - k.R).max() < POSE_TOLERANCE and np.abs(cam.t - k.t).max() < POSE_TOLERANCE
                   and np.abs(cam.K - k.K).max() < POSE_TOLERANCE for k in kept):
            kept.append(cam)
    return kept


def sphere_points(sphere: Sphere, cameras: list[PinholeCamera], width: int, height: int,
                  spacing_px: float) -> np.ndarray:
    """[N, 3] points where the cameras' rays through a grid of pixels meet the sphere from inside,
    thinned so that no two lie closer than the grid spacing seen from the nearest camera."""
    chunks, spacings = [], []
    for cam in distinct_cameras(cameras):
        offset = cam.centre - sphere.centre
        if np.linalg.norm(offset) >= sphere.radius:
            raise GlimpseError(
                f"04_bg_pretrain: a camera lies {np.linalg.norm(offset):.2f} units from the people's mean position, "
                f"outside the background sphere of radius {sphere.radius:.2f}; raise 04_bg_pretrain.sphere_radius_m")
        margin = GRID_MARGIN_CELLS * spacing_px
        u, v = np.meshgrid(np.arange(-margin, width + margin, spacing_px),
                           np.arange(-margin, height + margin, spacing_px))
        rays_cam = np.stack([(u.ravel() - cam.K[0, 2]) / cam.K[0, 0], (v.ravel() - cam.K[1, 2]) / cam.K[1, 1],
                             np.ones(u.size)], axis=1)
        rays = rays_cam @ cam.R  # camera to world: R^T d, row-wise
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        b = rays @ offset
        distance = -b + np.sqrt(b * b - (offset @ offset - sphere.radius**2))  # > 0: the camera is inside
        chunks.append(cam.centre + distance[:, None] * rays)
        spacings.append(spacing_px * distance.min() / max(cam.K[0, 0], cam.K[1, 1]))
    points = np.concatenate(chunks)
    if len(chunks) > 1:  # several viewpoints: drop points closer than the finest spacing to one kept
        points = _thin(points, min(spacings))
    return points


def _thin(points: np.ndarray, spacing: float) -> np.ndarray:
    """Keep the first point of each cell of a grid of side ``spacing`` (deterministic)."""
    cells = np.floor(points / spacing).astype(np.int64)
    _, first = np.unique(cells, axis=0, return_index=True)
    return points[np.sort(first)]


def colour_from_frames(points: np.ndarray, views: list[tuple[PinholeCamera, np.ndarray, np.ndarray]]
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Median colour of each point over ``views`` (camera, image [H, W, 3] uint8, background [H, W] bool)
    at the nearest pixel, counting only background pixels. Returns (rgb [N, 3] in [0, 1], seen [N] bool);
    unseen points take the colour of the nearest seen one."""
    samples = np.full((len(views), len(points), 3), np.nan, dtype=np.float32)
    for k, (cam, image, background) in enumerate(views):
        pixels, depth = cam.project(points)
        h, w = background.shape
        with np.errstate(invalid="ignore"):
            col, row = np.round(pixels[:, 0]), np.round(pixels[:, 1])
            inside = (depth > 0) & (col >= 0) & (col < w) & (row >= 0) & (row < h)
        col, row = col[inside].astype(np.int64), row[inside].astype(np.int64)
        usable = background[row, col]
        index = np.nonzero(inside)[0][usable]
        samples[k, index] = image[row[usable], col[usable]] / 255.0
    seen = ~np.isnan(samples[..., 0]).all(axis=0)
    rgb = np.full((len(points), 3), GREY, dtype=np.float32)
    if seen.any():
        rgb[seen] = np.nanmedian(samples[:, seen], axis=0)
        if not seen.all():
            _, nearest = cKDTree(points[seen]).query(points[~seen])
            rgb[~seen] = rgb[seen][nearest]
    return rgb, seen
