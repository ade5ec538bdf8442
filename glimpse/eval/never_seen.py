"""What stage 07 needs to score the regions no input frame saw, and the two baselines beside them.

- **Never-seen pixels** of a scored view: the people's fitted bodies (stage 06's refined poses) are
  rasterized together; a pixel is never-seen when the nearest body surface there is a triangle none
  of whose vertices any input frame saw (stage 06's ``visibility.npz``), and the ground truth shows
  a person there (its union mask).
- **Baselines**: an empty render (black), and every body drawn flat in its person's mean colour (the
  mean input-frame colour inside that person's stage-03 masks): what a reader gets for free, so the
  table shows what the reconstruction and the prior add.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from glimpse.body.models import BodyModels
from glimpse.eval.views import ScoredView
from glimpse.humans.person import PersonGaussians
from glimpse.humans.visibility import BodyVisibility, posed_vertices
from glimpse.io.images import frame_files, frame_name, read_mask, read_rgb
from glimpse.render.mesh_raster import rasterize_meshes


@dataclass(frozen=True)
class ViewBodies:
    """One scored view's bodies: owner [H, W] index into the people (-1: no body), never_seen [H, W] bool
    (the nearest body triangle has no vertex any input frame saw)."""

    owner: np.ndarray
    never_seen: np.ndarray


class PosedBodies:
    """Every person's fitted body in every frame they have (refined poses), and which triangles no input
    frame saw (none of their three vertices), for rasterizing scored views."""

    def __init__(self, people: list[PersonGaussians], visibility: dict[str, BodyVisibility], body_models: BodyModels):
        self.faces = body_models.faces.cpu().numpy()
        self.people = people
        self.vertices = [posed_vertices(body_models[p.pid], p.refined_body()) for p in people]  # [T, V, 3] each
        self.unseen_faces = [~visibility[p.pid].seen[self.faces].any(axis=1) for p in people]  # [F] each

    def in_view(self, view: ScoredView) -> ViewBodies:
        present = [k for k, p in enumerate(self.people) if p.in_frame(view.frame_id)]
        if not present:
            empty = np.full((view.camera.height, view.camera.width), -1, np.int64)
            return ViewBodies(empty, np.zeros((view.camera.height, view.camera.width), bool))
        camera = view.camera
        points = [self.vertices[k][self.people[k].row_of_frame[view.frame_id]] @ camera.R.T + camera.t
                  for k in present]
        count = len(self.faces)
        raster = rasterize_meshes(points, self.faces, camera.K, camera.width, camera.height)
        covered = raster.face >= 0
        slot = np.where(covered, raster.face // count, 0)
        owner = np.where(covered, np.asarray(present)[slot], -1)
        unseen = np.concatenate([self.unseen_faces[k] for k in present])
        never_seen = covered & unseen[np.where(covered, raster.face, 0)]
        return ViewBodies(owner, never_seen)


def person_mean_colours(frames_dir: Path, masks_dir: Path, pids: list[str], every: int) -> dict[str, np.ndarray]:
    """Per pid: mean RGB [3] in [0, 1] of the input frames (every ``every``-th) inside that person's stage-03
    mask; grey 0.5 for a person no mask covers."""
    sums = {pid: np.zeros(3) for pid in pids}
    counts = dict.fromkeys(pids, 0)
    frames = frame_files(frames_dir)
    for fid in sorted(frames)[::max(every, 1)]:
        image = None
        for pid in pids:
            path = masks_dir / pid / f"{frame_name(fid)}.png"
            if not path.is_file():
                continue
            mask = read_mask(path)
            if mask.any():
                image = read_rgb(frames[fid]) if image is None else image
                sums[pid] += image[mask].sum(axis=0) / 255.0
                counts[pid] += int(mask.sum())
    return {pid: sums[pid] / counts[pid] if counts[pid] else np.full(3, 0.5) for pid in pids}


def flat_bodies(bodies: ViewBodies, colours: list[np.ndarray]) -> np.ndarray:
    """[H, W, 3] in [0, 1]: each body pixel in its person's colour (``colours`` by person index), black elsewhere."""
    palette = np.concatenate([np.stack(colours), np.zeros((1, 3))]) if colours else np.zeros((1, 3))
    return palette[np.where(bodies.owner >= 0, bodies.owner, len(colours))].astype(np.float32)
