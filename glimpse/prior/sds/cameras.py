"""Where the SDS views look from (CONTRACTS.md "Shared samplers"; paper supplementary; GTU_REFERENCE.md 4).

All in the person's canonical body frame (y up, facing +z), the body posed about its own origin
with no root rotation (the official code renders the person alone this way), so azimuth 0 is the
front whatever the person did in the scene. Five kinds of view:

- ``full``: the person in one of their observed poses, a camera on the orbit (radius, azimuth
  U[-180, 180), elevation U[elevation_deg)) looking at the pelvis;
- ``canonical``: the same camera around the canonical (Da-pose) body;
- ``head``, ``upper``, ``lower``: zoomed on that part of an observed pose, from ``zoom_radius_m`` at
  elevation 0, the field of view cropped to the part's projected vertices times its ``zoom_scale``.

The kind is drawn with ``early`` probabilities for the first ``zoom_after`` SDS steps (full and
canonical only: supplementary), then with ``late`` ones (0.2 each).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from glimpse.cameras.model import PinholeCamera
from glimpse.cameras.orbit import box_centre, orbit_camera

VIEW_KINDS = ("full", "canonical", "head", "upper", "lower")
PLACEHOLDER_FOVY_DEG = 90.0  # a zoomed camera's pose comes from the orbit; its focal length is fitted after
MIN_HALF_EXTENT = 1e-6  # tangent of half the zoomed view: a part collapsed to a point still gets a camera
ZOOMED = ("head", "upper", "lower")
# body parts of the zoomed views, as SMPL joints whose vertices (skinning weights' argmax) they take
PART_JOINTS = {
    "head": (12, 15),
    "upper": (3, 6, 9, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23),
    "lower": (0, 1, 2, 4, 5, 7, 8, 10, 11),
}


@dataclass(frozen=True)
class SDSCameraConfig:
    radius_m: float                    # orbit radius (official: 2.2), times the person's scale
    fovy_deg: float                    # full and canonical views (official: 49.1)
    elevation_deg: list[float]         # [low, high] uniform range (paper: [-54, 54] = 0.3 pi; official config: [-30, 30))
    zoom_radius_m: float               # zoomed views' distance (official: 2.86)
    zoom_scale: dict[str, float]       # zoomed kind -> crop side over the part's projected extent
    zoom_after: int                    # SDS steps with the early probabilities (paper: 3000)
    early: dict[str, float]            # kind -> probability before zoom_after
    late: dict[str, float]             # kind -> probability after


@dataclass(frozen=True)
class SDSView:
    """One sampled SDS camera: its kind, the camera (a square image), where it stands."""

    kind: str
    camera: PinholeCamera
    azimuth_deg: float
    elevation_deg: float


def view_kind(step: int, config: SDSCameraConfig, rng: np.random.Generator) -> str:
    """The kind of view at SDS step ``step``, drawn with the early or late probabilities."""
    table = config.early if step < config.zoom_after else config.late
    kinds = [k for k in VIEW_KINDS if table.get(k, 0.0) > 0]
    weights = np.array([table[k] for k in kinds], np.float64)
    return kinds[int(rng.choice(len(kinds), p=weights / weights.sum()))]


def zoomed_camera(points: np.ndarray, azimuth_deg: float, radius: float, crop_scale: float,
                  size: int) -> PinholeCamera:
    """A camera at elevation 0 and ``azimuth_deg`` looking at the centre of ``points [N, 3]`` (a body part,
    body frame) from ``radius``, its field of view fitted to the points' projected extent x ``crop_scale``."""
    centre = box_centre(points)
    camera = orbit_camera(centre, azimuth_deg, 0.0, radius, PLACEHOLDER_FOVY_DEG, size)
    local = points @ camera.R.T + camera.t
    half = float(np.max(np.abs(local[:, :2] / local[:, 2:3]))) * crop_scale
    focal = 0.5 * size / max(half, MIN_HALF_EXTENT)
    K = camera.K.copy()
    K[0, 0] = K[1, 1] = focal
    return replace(camera, K=K)


def sample_view(kind: str, config: SDSCameraConfig, vertices: np.ndarray, labels: np.ndarray, pelvis: np.ndarray,
                scale: float, size: int, rng: np.random.Generator) -> SDSView:
    """A camera of ``kind`` (view_kind) around a body with vertices ``vertices [V, 3]`` and pelvis ``pelvis [3]``
    in the body frame (an observed pose with no root rotation, or the canonical one for ``canonical``);
    ``labels [V]`` each vertex's joint (skinning argmax); ``scale`` the person's size factor."""
    azimuth = float(rng.uniform(-180.0, 180.0))
    if kind in ZOOMED:
        part = vertices[np.isin(labels, PART_JOINTS[kind])]
        camera = zoomed_camera(part, azimuth, config.zoom_radius_m * scale, config.zoom_scale[kind], size)
        return SDSView(kind, camera, azimuth, 0.0)
    low, high = config.elevation_deg
    elevation = float(rng.uniform(low, high))
    camera = orbit_camera(pelvis, azimuth, elevation, config.radius_m * scale, config.fovy_deg, size)
    return SDSView(kind, camera, azimuth, elevation)


def fovy_deg(camera: PinholeCamera) -> float:
    """The vertical field of view of ``camera``, degrees."""
    return math.degrees(2.0 * math.atan(0.5 * camera.height / camera.K[1, 1]))
