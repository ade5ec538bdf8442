"""Camera paths for rendering a finished run: the input cameras, an orbit, a held-out camera, or a
list from a COLMAP text model or a Glimpse cameras.json (docs/renders.md).

An orbit turns a starting camera about the vertical axis through a centre point (the people's
mean pelvis at the chosen time): the camera keeps its height, distance and tilt relative to the
people. "Vertical" is the mean camera up vector of the input cameras (CONTRACTS.md "Up": no stage
assumes the world's up axis).
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from glimpse.cameras.model import PinholeCamera
from glimpse.errors import GlimpseError
from glimpse.io.cameras_json import read_cameras_json
from glimpse.io.colmap_model import PINHOLE_MODELS, read_colmap_model


def mean_up(cameras: list[PinholeCamera]) -> np.ndarray:
    """(3,) unit world vector: the mean of the cameras' up directions (OpenCV cameras: -y)."""
    up = -np.mean([camera.R[1] for camera in cameras], axis=0)
    norm = np.linalg.norm(up)
    if norm < 1e-9:
        raise GlimpseError("the input cameras' up vectors cancel out: no vertical axis for an orbit")
    return up / norm


def turned(camera: PinholeCamera, centre: np.ndarray, axis: np.ndarray, degrees: float) -> PinholeCamera:
    """``camera`` carried ``degrees`` about the line through ``centre`` along ``axis`` (right-handed): the
    world seen by the new camera is the old one's turned back by the same angle."""
    turn = Rotation.from_rotvec(np.radians(degrees) * axis).as_matrix()
    R = camera.R @ turn.T
    return replace(camera, K=camera.K.copy(), R=R, t=camera.t + camera.R @ centre - R @ centre)


def orbit_path(start: PinholeCamera, centre: np.ndarray, axis: np.ndarray, count: int,
               degrees: float = 360.0) -> list[PinholeCamera]:
    """``count`` cameras turning ``start`` by ``degrees`` in all about the axis through ``centre`` (the last
    shot stops one step short of a full circle, so a looped video does not repeat a frame)."""
    if count < 1:
        raise GlimpseError(f"an orbit needs at least one frame, got {count}")
    step = degrees / count if math.isclose(abs(degrees), 360.0) else degrees / max(count - 1, 1)
    return [turned(start, centre, axis, k * step) for k in range(count)]


def json_path(path: Path) -> list[PinholeCamera]:
    """Every camera of a Glimpse cameras.json (stage 01's format), in frame order."""
    _, _, cameras = read_cameras_json(path)
    return [cameras[fid] for fid in sorted(cameras)]


def colmap_path(folder: Path) -> list[PinholeCamera]:
    """Every image of a COLMAP model (text or binary), in name order; pinhole camera models only."""
    shots = read_colmap_model(folder)
    for shot in shots:
        if shot.model not in PINHOLE_MODELS:
            raise GlimpseError(f"{folder}: image {shot.name} has a {shot.model} camera; only "
                               f"{' and '.join(PINHOLE_MODELS)} can be rendered (undistort the model first)")
    return [PinholeCamera(shot.K, shot.R, shot.t, shot.width, shot.height) for shot in shots]
