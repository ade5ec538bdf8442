"""Holes in a person's canonical Gaussians: how much of the body's own silhouette they leave see-through.

The person is rendered alone in the canonical pose from ``views`` azimuths evenly spread over a turn
(elevation 0, the turntables' cameras, glimpse.cameras.orbit.turn_cameras); the fitted body's mesh,
rasterized from the same cameras and eroded by ``erode_px`` (its outline is allowed to be soft),
says where the person should be opaque. A hole is a pixel there whose alpha is below
``alpha_below``. The share of holes is reported per person; 0 means the body is covered everywhere.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from glimpse.cameras.model import render_camera
from glimpse.cameras.orbit import box_centre, turn_cameras
from glimpse.humans.person import PersonGaussians
from glimpse.morphology import disk
from glimpse.render import RenderConfig, rasterize
from glimpse.render.mesh_raster import rasterize_triangles


@dataclass(frozen=True)
class CoverageConfig:
    views: int = 8              # azimuths over one turn
    size_px: int = 256          # square renders
    radius_m: float = 2.6       # camera distance from the body's centre (the turntables')
    fovy_deg: float = 49.1      # vertical field of view (the turntables')
    erode_px: float = 2.0       # the body's silhouette is shrunk by this many pixels
    alpha_below: float = 0.5    # a silhouette pixel with less alpha is a hole


@torch.no_grad()
def canonical_hole_share(person: PersonGaussians, faces: np.ndarray, config: CoverageConfig, render: RenderConfig,
                         device: torch.device) -> float:
    """Share (0..1) of the person's canonical body-silhouette pixels (the body model's ``faces [F, 3]`` over
    the rig's canonical vertices), over every view, that their Gaussians leave more transparent than
    ``config.alpha_below``."""
    points = person.rig.canonical_vertices.double().cpu().numpy()
    centre = box_centre(points)
    size = config.size_px
    holes = pixels = 0
    for pinhole in turn_cameras(np.tile(centre, (config.views, 1)), config.radius_m, config.fovy_deg, size):
        body = rasterize_triangles(points @ pinhole.R.T + pinhole.t, faces, pinhole.K, size, size).face >= 0
        inside = disk(body, config.erode_px, grow=False)
        alpha = rasterize(render_camera(pinhole, device), **person.model.render_inputs(0),
                          settings=render).alpha.reshape(size, size).cpu().numpy()
        holes += int((alpha[inside] < config.alpha_below).sum())
        pixels += int(inside.sum())
    return holes / max(pixels, 1)
