"""Reading a COLMAP model (text or binary, through pycolmap) as Glimpse cameras: OpenCV intrinsics (the
top-left pixel's centre at (0, 0), where COLMAP puts it at (0.5, 0.5)), OpenCV distortion coefficients, and
world-to-camera poses. The camera models that OpenCV's distortion can express are read; others are refused."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from glimpse.errors import GlimpseError
from glimpse.io.colmap_text import COLMAP_PIXEL_OFFSET

# COLMAP model -> how its parameters split into (focal lengths, principal point, OpenCV k1, k2, p1, p2)
FOCALS = {"SIMPLE_PINHOLE": 1, "PINHOLE": 2, "SIMPLE_RADIAL": 1, "RADIAL": 1, "OPENCV": 2}
PINHOLE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE")


@dataclass(frozen=True)
class ColmapShot:
    """One registered image: ``name`` as in images.txt, K [3, 3] (OpenCV pixel centres), dist [4] (OpenCV k1,
    k2, p1, p2; None for a pinhole model), R [3, 3] and t [3] world to camera (the model's units)."""

    name: str
    model: str
    K: np.ndarray
    dist: np.ndarray | None
    R: np.ndarray
    t: np.ndarray
    width: int
    height: int


def colmap_intrinsics(model: str, params: list[float], where: str) -> tuple[np.ndarray, np.ndarray | None]:
    """(K [3, 3] with OpenCV pixel centres, dist [4] or None) of a COLMAP camera ``model`` with ``params``."""
    if model not in FOCALS:
        raise GlimpseError(f"{where}: COLMAP camera model {model}; Glimpse reads {', '.join(FOCALS)}")
    count = FOCALS[model]
    fx, fy = (params[0], params[0]) if count == 1 else (params[0], params[1])
    cx, cy = params[count] - COLMAP_PIXEL_OFFSET, params[count + 1] - COLMAP_PIXEL_OFFSET
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    if model in PINHOLE_MODELS:
        return K, None
    dist = np.zeros(4)
    extra = params[count + 2:]
    dist[: len(extra)] = extra  # SIMPLE_RADIAL: k1; RADIAL: k1, k2; OPENCV: k1, k2, p1, p2
    return K, dist


def read_colmap_model(folder: Path) -> list[ColmapShot]:
    """Every registered image of the model in ``folder`` (cameras, images, points3D as .txt or .bin), in name
    order."""
    import pycolmap

    folder = Path(folder)
    if not any((folder / f"images{ext}").is_file() for ext in (".txt", ".bin")):
        raise GlimpseError(f"{folder}: no COLMAP model (cameras, images and points3D as .txt or .bin)")
    try:
        model = pycolmap.Reconstruction(str(folder))
    except Exception as exc:  # pycolmap raises its own error types for unreadable models
        raise GlimpseError(f"{folder}: not a readable COLMAP model ({exc})") from None
    shots = []
    for image in sorted(model.images.values(), key=lambda i: i.name):
        camera = model.cameras[image.camera_id]
        K, dist = colmap_intrinsics(camera.model.name, [float(p) for p in camera.params],
                                    f"{folder} camera {image.camera_id}")
        pose = image.cam_from_world()
        shots.append(ColmapShot(image.name, camera.model.name, K, dist, pose.rotation.matrix(),
                                np.asarray(pose.translation, dtype=np.float64), int(camera.width),
                                int(camera.height)))
    if not shots:
        raise GlimpseError(f"{folder}: the COLMAP model has no registered image")
    return shots
