"""Which parts of each person's body the input frames saw, per body vertex.

A vertex of a person's fitted body counts as seen in a frame when, in that frame's camera:
- it projects inside the image, in front of the camera;
- it is the nearest surface at its pixel, within ``depth_tolerance_m`` (every person's body is in
  the z-buffer, so people hide each other);
- its pixel is in the person's visible mask (stage 03): a static occluder (a table before the legs)
  or another person there means the camera saw something else;
- the camera sees its surface at most ``max_view_angle_deg`` from head-on (grazing views teach little).

Per vertex the record keeps how many frames saw it, the most head-on cosine and the finest
resolution (pixels per metre of body) among them. Stage 06 writes it per person
(``humans/<pid>/visibility.npz``); the surface prior reads it to tell seen Gaussians from unseen
ones, and stage 07 uses it for the never-seen-region metrics.
"""

from __future__ import annotations

from collections.abc import Mapping

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from glimpse.body.model import BodyModel
from glimpse.body.models import BodyModels
from glimpse.body.normals import vertex_normals
from glimpse.body.params import BodyParams
from glimpse.cameras.model import PinholeCamera
from glimpse.errors import GlimpseError
from glimpse.render.mesh_raster import NEAR, rasterize_meshes

VISIBILITY_FORMAT = "glimpse-visibility/1"


@dataclass(frozen=True)
class VisibilityConfig:
    depth_tolerance_m: float
    max_view_angle_deg: float


@dataclass
class BodyVisibility:
    """Per body vertex: seen_frames [V] int, best_cosine [V] (0 where never seen), best_px_per_m [V]
    (pixels per metre of body at the finest view that saw it; 0 where never seen)."""

    seen_frames: np.ndarray
    best_cosine: np.ndarray
    best_px_per_m: np.ndarray

    @classmethod
    def empty(cls, vertex_count: int) -> BodyVisibility:
        return cls(np.zeros(vertex_count, np.int64), np.zeros(vertex_count), np.zeros(vertex_count))

    @property
    def seen(self) -> np.ndarray:
        """[V] bool: seen in at least one input frame."""
        return self.seen_frames > 0

    def add(self, seen: np.ndarray, cosine: np.ndarray, px_per_m: np.ndarray) -> None:
        """Accumulate one frame: seen [V] bool, cosine [V], px_per_m [V]."""
        self.seen_frames += seen
        self.best_cosine = np.maximum(self.best_cosine, np.where(seen, cosine, 0.0))
        self.best_px_per_m = np.maximum(self.best_px_per_m, np.where(seen, px_per_m, 0.0))

    def write(self, path: Path) -> None:
        np.savez(path, format=np.array(VISIBILITY_FORMAT), seen_frames=self.seen_frames,
                 best_cosine=self.best_cosine, best_px_per_m=self.best_px_per_m)

    @classmethod
    def read(cls, path: Path) -> BodyVisibility:
        with np.load(path) as data:
            if "format" not in data or str(data["format"]) != VISIBILITY_FORMAT:
                raise GlimpseError(f"{path}: not a {VISIBILITY_FORMAT} file; rerun stage 06")
            return cls(data["seen_frames"], data["best_cosine"], data["best_px_per_m"])


def frame_visibility(bodies: list[np.ndarray], scales: list[float], faces: np.ndarray, camera: PinholeCamera,
                     width: int, height: int, visible: list[np.ndarray | None], config: VisibilityConfig
                     ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per body (vertices [V, 3] world, ``scales`` world units per metre): (seen [V] bool, cosine [V] of the
    viewing angle, px_per_m [V]) in one frame. ``visible`` per body: the pixels [H, W] bool where that person
    is visible, or None where no mask is known (the geometry alone decides)."""
    cam = [v @ camera.R.T + camera.t for v in bodies]
    if not cam:
        return []
    raster = rasterize_meshes(cam, faces, camera.K, width, height)
    focal = 0.5 * (camera.K[0, 0] + camera.K[1, 1])
    cos_min = math.cos(math.radians(config.max_view_angle_deg))
    result = []
    for points, scale, mask in zip(cam, scales, visible):
        z = points[:, 2]
        front = z > NEAR
        safe_z = np.where(front, z, 1.0)
        u = np.rint(points[:, 0] / safe_z * camera.K[0, 0] + camera.K[0, 2]).astype(np.int64)
        v = np.rint(points[:, 1] / safe_z * camera.K[1, 1] + camera.K[1, 2]).astype(np.int64)
        inside = front & (u >= 0) & (u < width) & (v >= 0) & (v < height)
        uc, vc = np.clip(u, 0, width - 1), np.clip(v, 0, height - 1)
        nearest = z <= raster.depth[vc, uc] + config.depth_tolerance_m * scale
        towards_camera = -points / np.linalg.norm(points, axis=1, keepdims=True).clip(min=NEAR)
        cosine = (vertex_normals(points, faces) * towards_camera).sum(1)
        seen = inside & nearest & (cosine >= cos_min)
        if mask is not None:
            seen &= mask[vc, uc]
        result.append((seen, cosine, focal * scale / safe_z))
    return result


def posed_vertices(body_model: BodyModel, params: BodyParams, rows: slice = slice(None)) -> np.ndarray:
    """[T, V, 3] the body of the frames ``rows`` of ``params`` (default all), world frame."""
    with torch.no_grad():
        out = body_model(torch.as_tensor(params.betas), torch.as_tensor(params.global_orient[rows]),
                         torch.as_tensor(params.body_pose[rows]), torch.as_tensor(params.transl[rows]),
                         scale=params.scale)
    return out.vertices.double().numpy()


def body_visibility(models: BodyModels, bodies: dict[str, BodyParams], cameras: dict[int, PinholeCamera],
                    width: int, height: int, visible: Mapping[int, dict[str, np.ndarray]], config: VisibilityConfig
                    ) -> dict[str, BodyVisibility]:
    """Every person's vertex visibility over the frames with a camera (``models``: each person's body model);
    ``visible[frame id][pid]`` [H, W] bool: where that person is visible in that frame (stage 03's masks; no
    entry: no mask, geometry alone). ``visible`` may read each frame's masks when asked: frames are visited
    once, in order."""
    faces = models.faces.numpy()
    vertex_count = models.default.num_vertices
    records = {pid: BodyVisibility.empty(vertex_count) for pid in bodies}
    rows = {pid: {int(f): r for r, f in enumerate(params.frame_ids)} for pid, params in bodies.items()}
    for fid in sorted(cameras):  # one frame at a time: a long video's bodies and masks are never all held
        present = [pid for pid in sorted(bodies) if fid in rows[pid]]
        posed = [posed_vertices(models[pid], bodies[pid], slice(rows[pid][fid], rows[pid][fid] + 1))[0]
                 for pid in present]
        seen = frame_visibility(posed, [float(bodies[pid].scale) for pid in present], faces, cameras[fid], width,
                                height, [visible.get(fid, {}).get(pid) for pid in present], config)
        for pid, (mask, cosine, px_per_m) in zip(present, seen):
            records[pid].add(mask, cosine, px_per_m)
    return records
