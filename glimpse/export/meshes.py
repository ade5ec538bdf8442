"""Each person's fitted body as a coloured triangle mesh per frame, for Blender and other mesh tools: the body
model posed by the run's refined parameters (exact SMPL-format posing, then the person's scale and
translation), coloured per vertex by the Gaussians nearest to it in the canonical body, written as binary glTF
through trimesh (MIT)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree

from glimpse.body.model import BodyModel
from glimpse.humans.person import PersonGaussians
from glimpse.render.sh import sh_dc_to_rgb

UNCOLOURED = -1  # a vertex no Gaussian is nearest to (it takes its nearest coloured vertex's colour)


def vertex_colours(vertices: np.ndarray, means: np.ndarray, rgb: np.ndarray, opacities: np.ndarray) -> np.ndarray:
    """[V, 3] colours in [0, 1] of body ``vertices [V, 3]``: the opacity-weighted mean colour ``rgb [N, 3]`` of the
    Gaussians (centres ``means [N, 3]``, same frame) whose nearest vertex each is; a vertex without any takes the
    colour of the nearest vertex with some (grey when no Gaussian has any opacity)."""
    _, nearest = cKDTree(vertices).query(means)
    mass = np.bincount(nearest, weights=opacities, minlength=len(vertices))
    total = np.stack([np.bincount(nearest, weights=opacities * rgb[:, c], minlength=len(vertices))
                      for c in range(3)], axis=1)
    coloured = mass > 0
    if not coloured.any():
        return np.full((len(vertices), 3), 0.5)
    colours = np.where(coloured[:, None], total / np.maximum(mass, 1e-12)[:, None], 0.0)
    _, source = cKDTree(vertices[coloured]).query(vertices[~coloured])
    colours[~coloured] = colours[coloured][source]
    return colours


@torch.no_grad()
def person_vertex_colours(person: PersonGaussians) -> np.ndarray:
    """[V, 3] the person's body-vertex colours from their canonical Gaussians (vertex_colours)."""
    model = person.model
    return vertex_colours(person.rig.canonical_vertices.double().cpu().numpy(),
                          model.means.detach().double().cpu().numpy(),
                          sh_dc_to_rgb(model.sh_dc.detach()[:, 0]).clamp(0.0, 1.0).double().cpu().numpy(),
                          model.opacities().detach().double().cpu().numpy())


@torch.no_grad()
def posed_vertices(body_model: BodyModel, person: PersonGaussians, frame_id: int) -> np.ndarray:
    """[V, 3] the person's body at ``frame_id`` in the world (refined pose, their scale and translation)."""
    body = person.refined_body()
    row = int(np.flatnonzero(body.frame_ids == frame_id)[0])
    out = body_model(torch.as_tensor(body.betas[None]), torch.as_tensor(body.global_orient[row:row + 1]),
                     torch.as_tensor(body.body_pose[row:row + 1]), torch.as_tensor(body.transl[row:row + 1]),
                     torch.as_tensor([body.scale]))
    return out.vertices[0].double().cpu().numpy()


def write_mesh_glb(path: Path, vertices: np.ndarray, faces: np.ndarray, colours: np.ndarray) -> None:
    """A binary glTF of one triangle mesh with per-vertex colours (``colours [V, 3]`` in [0, 1])."""
    import trimesh

    rgba = np.concatenate([np.round(colours * 255.0), np.full((len(colours), 1), 255.0)], axis=1).astype(np.uint8)
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, vertex_colors=rgba, process=False)
    path.write_bytes(mesh.export(file_type="glb"))
