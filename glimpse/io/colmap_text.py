"""COLMAP text models (cameras.txt, images.txt, points3D.txt) for users' tools.

COLMAP puts the centre of the top-left pixel at (0.5, 0.5); Glimpse (OpenCV) at
(0, 0). The principal point is shifted by +0.5 on write. Cameras are PINHOLE.
Tracks are not written (empty point lists), which COLMAP's readers accept.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from glimpse.cameras.model import PinholeCamera
from glimpse.io.images import frame_name

COLMAP_PIXEL_OFFSET = 0.5  # COLMAP pixel-centre convention minus OpenCV's


def write_colmap_text(
    folder: Path, width: int, height: int, cameras: dict[int, PinholeCamera], image_ext: str,
    xyz: np.ndarray | None = None, rgb: np.ndarray | None = None,
) -> None:
    """Write a COLMAP text model of ``cameras`` (frame id -> camera) and optional points."""
    folder.mkdir(parents=True, exist_ok=True)
    intrinsics: list[tuple[float, ...]] = []
    cam_lines, img_lines = [], []
    for image_id, fid in enumerate(sorted(cameras), start=1):
        cam = cameras[fid]
        params = (cam.K[0, 0], cam.K[1, 1], cam.K[0, 2] + COLMAP_PIXEL_OFFSET, cam.K[1, 2] + COLMAP_PIXEL_OFFSET)
        if params not in intrinsics:
            intrinsics.append(params)
            cam_lines.append(f"{len(intrinsics)} PINHOLE {width} {height} " + " ".join(f"{p:.10g}" for p in params))
        camera_id = intrinsics.index(params) + 1
        qx, qy, qz, qw = Rotation.from_matrix(cam.R).as_quat()
        pose = " ".join(f"{v:.12g}" for v in (qw, qx, qy, qz, *cam.t))
        img_lines += [f"{image_id} {pose} {camera_id} {frame_name(fid)}{image_ext}", ""]
    (folder / "cameras.txt").write_text(
        "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
        + "\n".join(cam_lines) + "\n"
    )
    (folder / "images.txt").write_text(
        "# Image list with two lines of data per image:\n"
        "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n#   POINTS2D[] as (X, Y, POINT3D_ID)\n"
        + "\n".join(img_lines) + "\n"
    )
    lines = ["# 3D point list with one line of data per point:",
             "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)"]
    if xyz is not None and rgb is not None:
        for i, (p, c) in enumerate(zip(xyz, rgb), start=1):
            lines.append(f"{i} {p[0]:.8g} {p[1]:.8g} {p[2]:.8g} {int(c[0])} {int(c[1])} {int(c[2])} 0")
    (folder / "points3D.txt").write_text("\n".join(lines) + "\n")
