"""A finished run's Gaussians and cameras in the formats users' tools open (docs/exports.md).

    OUT/
      scene_<frame>.ply               background + every person present, posed at that frame (standard 3DGS);
                                      one per exported frame, a sequence a splat viewer can play
      people/<pid>/canonical.ply      the person in canonical (Da-pose) space, SH in the canonical frame
      people/<pid>/posed_<frame>.ply  the person alone at that frame (standard 3DGS)
      people/<pid>/mesh_<frame>.glb   the fitted body at that frame, coloured by the Gaussians (binary glTF)
      people/<pid>/body.npz           refined body parameters of every frame (glimpse body parameters)
      people/<pid>/skinning.npz       skinning-weight grid (glimpse-skinning/1)
      cameras/                        the input cameras as a COLMAP text model
      export.json                     what was exported from which run, and the world frame
"""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np

from glimpse.cameras.align import rotation_between
from glimpse.errors import GlimpseError
from glimpse.export.meshes import person_vertex_colours, posed_vertices, write_mesh_glb
from glimpse.export.splats import frame_splats, posed_person_splats, rotated_splats, with_sh_degree
from glimpse.gaussians.ply import GaussianSplats, write_gaussians_ply
from glimpse.io.colmap_text import write_colmap_text
from glimpse.io.images import frame_name
from glimpse.io.progress import progress
from glimpse.io.staging import staged_folder
from glimpse.replay.cameras import mean_up
from glimpse.replay.finished import FinishedRun

EXPORT_FORMAT = "glimpse-export/2"  # 2: lists of frames and scenes, up and world_rotation
PERSON_FILES = ("canonical.ply", "body.npz", "skinning.npz")


def _degree(splats: GaussianSplats, sh_degree: int | None) -> GaussianSplats:
    return splats if sh_degree is None else with_sh_degree(splats, sh_degree)


UP_AXES = {"y": np.array([0.0, 1.0, 0.0]), "z": np.array([0.0, 0.0, 1.0])}  # keep: the run's own frame


def world_rotation(run: FinishedRun, up: str) -> np.ndarray:
    """[3, 3] the rotation of the exported world: the input cameras' mean up vector onto +y (y-up viewers) or
    +z (z-up tools), or none (``keep``: stage 01's frame)."""
    if up == "keep":
        return np.eye(3)
    if up not in UP_AXES:
        raise GlimpseError(f"--up {up!r}: use y, z or keep")
    return rotation_between(mean_up(list(run.cameras.values())), UP_AXES[up])


def export_run(run: FinishedRun, frame_ids: list[int], out: Path, sh_degree: int | None = None, up: str = "y"
               ) -> Path:
    """Write the export of ``frame_ids`` (one scene PLY and one posed PLY per person present, each frame) to
    ``out`` (replaced whole, written beside it first); returns ``out``. ``sh_degree``: the posed PLYs' SH degree
    (None: as trained; 3 for viewers that read only degree 3). ``up``: world_rotation's."""
    missing = [f for f in frame_ids if f not in run.cameras]
    if missing or not frame_ids:
        raise GlimpseError(f"frames {missing or frame_ids}: not input frames with a camera in {run.folder / '01_sfm'} "
                           f"(frames {min(run.cameras)}..{max(run.cameras)})")
    turn = world_rotation(run, up)
    with staged_folder(out) as tmp:
        _write_export(run, frame_ids, sh_degree, up, turn, tmp)
    return out


def _write_export(run: FinishedRun, frame_ids: list[int], sh_degree: int | None, up: str, turn: np.ndarray,
                  tmp: Path) -> None:
    """export_run's files, into the staging folder ``tmp``."""

    def written(splats: GaussianSplats) -> GaussianSplats:
        return rotated_splats(_degree(splats, sh_degree), turn)

    (tmp / "people").mkdir()
    scenes, people_doc = [], {}
    faces = run.body_models.faces.cpu().numpy()
    colours = {person.pid: person_vertex_colours(person) for person in run.people}
    for person in run.people:
        (tmp / "people" / person.pid).mkdir()
        for file in PERSON_FILES:
            shutil.copy2(run.folder / "06_joint_opt" / "humans" / person.pid / file, tmp / "people" / person.pid / file)
        people_doc[person.pid] = {"gaussians": len(person.model), "files": list(PERSON_FILES)}
    for frame_id in progress(frame_ids, desc="export", unit="frame"):
        name = frame_name(frame_id)
        scenes.append(f"scene_{name}.ply")
        write_gaussians_ply(tmp / scenes[-1], written(frame_splats(run.background, run.people, frame_id)),
                            {"frame": name, "up": up})
        for person in run.people:
            if person.in_frame(frame_id):
                write_gaussians_ply(tmp / "people" / person.pid / f"posed_{name}.ply",
                                    written(posed_person_splats(person, frame_id)), {"frame": name, "up": up})
                vertices = posed_vertices(run.body_models[person.pid], person, frame_id) @ turn.T
                write_mesh_glb(tmp / "people" / person.pid / f"mesh_{name}.glb", vertices, faces, colours[person.pid])
                people_doc[person.pid]["files"] += [f"posed_{name}.ply", f"mesh_{name}.glb"]
    cameras = {fid: replace(camera, R=camera.R @ turn.T) for fid, camera in run.cameras.items()}
    write_colmap_text(tmp / "cameras", run.width, run.height, cameras, ".png")
    doc = {"format": EXPORT_FORMAT, "run": str(run.folder.resolve()), "frames": frame_ids, "scenes": scenes,
           "people": people_doc, "cameras": "cameras/ (COLMAP text model, PINHOLE, images named as 01_sfm/frames)",
           "up": up, "world_rotation": turn.round(12).tolist(),
           "world": "stage 01's world frame (CONTRACTS.md) turned by world_rotation (exported point = world_rotation "
                    "@ run point): the scene's cameras.json frame when given, the static camera's (x right, y down, "
                    "z forward), or structure from motion's (its own units); canonical.ply, body.npz and "
                    "skinning.npz stay in the run's frames"}
    (tmp / "export.json").write_text(json.dumps(doc, indent=2) + "\n")
