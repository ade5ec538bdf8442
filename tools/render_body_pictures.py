"""Pictures of the free body for docs/body.md: a turntable of the neutral body, the
shape presets, and the built-in motions. A painter's-algorithm triangle renderer
(flat Lambert shading) keeps this free of GPU and mesh-renderer dependencies.

    .venv/bin/python tools/render_body_pictures.py    # writes docs/images/free_body_*.png
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from glimpse.body.model import BodyModel  # noqa: E402
from glimpse.body.motion import BUILTIN_MOTIONS, builtin_motion  # noqa: E402
from glimpse.config import REPO_ROOT  # noqa: E402

TILE = 240  # pixels per picture tile
LIGHT = np.array([0.3, 0.5, 1.0]) / np.linalg.norm([0.3, 0.5, 1.0])
BODY_COLOUR = np.array([200, 170, 150])  # BGR
BACKGROUND = 255
AZIMUTHS_DEG = (0, 45, 90, 135, 180, 225, 270, 315)


def render(vertices: np.ndarray, faces: np.ndarray, azimuth_deg: float, label: str = "") -> np.ndarray:
    """Orthographic view of a mesh (y up) turned by azimuth about y, framed to fit the tile."""
    a = np.radians(azimuth_deg)
    rot = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    v = vertices @ rot.T
    centre = (v.max(0) + v.min(0)) / 2
    scale = 0.85 * TILE / max(np.ptp(v[:, 0]), np.ptp(v[:, 1]), 2.0)
    xy = np.stack([(v[:, 0] - centre[0]) * scale + TILE / 2, (centre[1] - v[:, 1]) * scale + TILE / 2], 1)
    tri = v[faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True) + 1e-12
    shade = 0.25 + 0.75 * np.clip(normals @ LIGHT, 0, 1)
    image = np.full((TILE, TILE, 3), BACKGROUND, np.uint8)
    visible = normals[:, 2] > 0  # facing the viewer (+z)
    for f in np.nonzero(visible)[0][np.argsort(tri[visible, :, 2].mean(1))]:  # far to near
        cv2.fillConvexPoly(image, np.round(xy[faces[f]] * 16).astype(np.int32),
                           (BODY_COLOUR * shade[f]).tolist(), cv2.LINE_AA, shift=4)
    if label:
        cv2.putText(image, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (60, 60, 60), 1, cv2.LINE_AA)
    return image


def main() -> None:
    model = BodyModel.from_file(REPO_ROOT / "glimpse/body/assets/free_body.npz", dtype=torch.float64)
    faces = model.faces.numpy()
    zero = torch.zeros(1, 3, dtype=torch.float64)

    def mesh(betas=None, orient=zero, body_pose=None, transl=None) -> np.ndarray:
        betas = torch.zeros(1, 10, dtype=torch.float64) if betas is None else torch.as_tensor(betas)[None]
        body_pose = torch.zeros(1, 69, dtype=torch.float64) if body_pose is None else body_pose
        return model(betas, orient, body_pose, transl).vertices[0].numpy()

    out = REPO_ROOT / "docs" / "images"
    out.mkdir(parents=True, exist_ok=True)
    neutral = mesh()
    cv2.imwrite(str(out / "free_body_turntable.png"),
                np.hstack([render(neutral, faces, az, f"{az} deg") for az in AZIMUTHS_DEG]))
    names = [str(n) for n in model.data.extras["shape_preset_names"]]
    presets = model.data.extras["shape_preset_betas"].astype(np.float64)
    shapes = [render(mesh(b), faces, 20, n) for n, b in zip(names, presets)]
    cv2.imwrite(str(out / "free_body_shapes.png"), np.hstack(shapes))
    tiles = []
    for name in BUILTIN_MOTIONS:
        seq = builtin_motion(name, n_frames=30, fps=30)
        for frame in (5, 15, 25):
            pose = torch.as_tensor(seq.body_pose[frame : frame + 1])
            orient = torch.as_tensor(seq.global_orient[frame : frame + 1])
            tiles.append(render(mesh(orient=orient, body_pose=pose), faces, 60, f"{name} {frame}"))
    rows = [np.hstack(tiles[i : i + 6]) for i in range(0, len(tiles), 6)]
    cv2.imwrite(str(out / "free_body_motions.png"), np.vstack(rows))
    print(f"wrote {out}/free_body_turntable.png, free_body_shapes.png, free_body_motions.png")


if __name__ == "__main__":
    main()
