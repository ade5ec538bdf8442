"""Cameras on an orbit around a person in the canonical body frame (CONTRACTS.md "Up": SMPL axes,
y up, the body facing +z), as the priors and turntables use them (GTU: radius 2.2 m, vertical field
of view 49.1°, elevation U[-30°, 30°), azimuth U[-180°, 180°)).

Azimuth 0 looks at the person's front (the camera on +z); positive azimuth moves the camera
towards the body's left (+x). Positive elevation raises the camera.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from glimpse.cameras.model import PinholeCamera


@dataclass(frozen=True)
class OrbitConfig:
    radius_m: float
    fovy_deg: float
    elevation_deg: list[float]  # [low, high)
    size_px: int


@dataclass(frozen=True)
class OrbitView:
    """One orbit camera (a square image) and where it stands."""

    camera: PinholeCamera
    azimuth_deg: float
    elevation_deg: float


def box_centre(points: np.ndarray) -> np.ndarray:
    """[3] the centre of the axis-aligned box around ``points [N, 3]`` (what orbits and turntables circle)."""
    return 0.5 * (points.min(0) + points.max(0))


def orbit_camera(centre: np.ndarray, azimuth_deg: float, elevation_deg: float, radius: float, fovy_deg: float,
                 size: int) -> PinholeCamera:
    """An OpenCV camera ``radius`` from ``centre [3]`` (canonical frame) looking at it, level with the body's up."""
    azimuth, elevation = math.radians(azimuth_deg), math.radians(elevation_deg)
    offset = radius * np.array([math.cos(elevation) * math.sin(azimuth), math.sin(elevation),
                                math.cos(elevation) * math.cos(azimuth)])
    position = np.asarray(centre, np.float64) + offset
    forward = -offset / radius
    right = np.cross(forward, [0.0, 1.0, 0.0])  # image x; y down is forward x right
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    R = np.stack([right, down, forward])
    focal = 0.5 * size / math.tan(math.radians(fovy_deg) / 2)
    K = np.array([[focal, 0.0, (size - 1) / 2], [0.0, focal, (size - 1) / 2], [0.0, 0.0, 1.0]])
    return PinholeCamera(K, R, -R @ position, size, size)


def turn_cameras(centres: np.ndarray, radius: float, fovy_deg: float, size: int) -> list[PinholeCamera]:
    """One camera per row of ``centres [K, 3]`` (canonical frame, y up), the k-th at azimuth 360 k / K (0 = the
    front), elevation 0, ``radius`` from its centre: one turn around a body (turntables, speed timings)."""
    return [orbit_camera(centre, 360.0 * k / len(centres), 0.0, radius, fovy_deg, size)
            for k, centre in enumerate(centres)]


def sample_orbit_views(centre: np.ndarray, count: int, config: OrbitConfig, rng: np.random.Generator) -> list[OrbitView]:
    """``count`` cameras with azimuth U[-180, 180) and elevation U[config.elevation_deg)."""
    low, high = config.elevation_deg
    views = []
    for _ in range(count):
        azimuth, elevation = float(rng.uniform(-180.0, 180.0)), float(rng.uniform(low, high))
        views.append(OrbitView(orbit_camera(centre, azimuth, elevation, config.radius_m, config.fovy_deg,
                                            config.size_px), azimuth, elevation))
    return views
