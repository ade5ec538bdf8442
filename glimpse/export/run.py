"""A finished run's Gaussians and cameras in the formats users' tools open (docs/exports.md).

    OUT/
      scene_<frame>.ply               background + every person present, posed at that frame (standard 3DGS)
      people/<pid>/canonical.ply      the person in canonical (Da-pose) space, SH in the canonical frame
      people/<pid>/posed_<frame>.ply  the person alone at that frame (standard 3DGS)
      people/<pid>/body.npz           refined body parameters of every frame (glimpse body parameters)
      people/<pid>/skinning.npz       skinning-weight grid (glimpse-skinning/1)
      cameras/                        the input cameras as a COLMAP text model
      export.json                     what was exported from which run, and the world frame
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from glimpse.errors import GlimpseError
from glimpse.export.splats import frame_splats, posed_person_splats, with_sh_degree
from glimpse.gaussians.ply import GaussianSplats, write_gaussians_ply
from glimpse.io.colmap_text import write_colmap_text
from glimpse.io.images import frame_name
from glimpse.replay.finished import FinishedRun

EXPORT_FORMAT = "glimpse-export/1"
PERSON_FILES = ("canonical.ply", "body.npz", "skinning.npz")


def _degree(splats: GaussianSplats, sh_degree: int | None) -> GaussianSplats:
    return splats if sh_degree is None else with_sh_degree(splats, sh_degree)


def export_run(run: FinishedRun, frame_id: int, out: Path, sh_degree: int | None = None) -> Path:
    """Write the export of ``frame_id`` to ``out`` (replaced whole, written beside it first); returns ``out``.
    ``sh_degree``: the posed PLYs' SH degree (None: as trained; 3 for viewers that read only degree 3)."""
    if frame_id not in run.cameras:
        raise GlimpseError(f"frame {frame_id}: not an input frame with a camera in {run.folder / '01_sfm'} "
                           f"(frames {min(run.cameras)}..{max(run.cameras)})")
    name = frame_name(frame_id)
    tmp = out.with_name(out.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    (tmp / "people").mkdir(parents=True)
    scene_ply = f"scene_{name}.ply"
    write_gaussians_ply(tmp / scene_ply, _degree(frame_splats(run.background, run.people, frame_id), sh_degree),
                        {"frame": name})
    people_doc = {}
    for person in run.people:
        folder = tmp / "people" / person.pid
        folder.mkdir()
        for file in PERSON_FILES:
            shutil.copy2(run.folder / "06_joint_opt" / "humans" / person.pid / file, folder / file)
        files = list(PERSON_FILES)
        if person.in_frame(frame_id):
            write_gaussians_ply(folder / f"posed_{name}.ply", _degree(posed_person_splats(person, frame_id), sh_degree),
                                {"frame": name})
            files.append(f"posed_{name}.ply")
        people_doc[person.pid] = {"gaussians": len(person.model), "files": files}
    write_colmap_text(tmp / "cameras", run.width, run.height, run.cameras, ".png")
    doc = {"format": EXPORT_FORMAT, "run": str(run.folder.resolve()), "frame": frame_id, "scene": scene_ply,
           "people": people_doc, "cameras": "cameras/ (COLMAP text model, PINHOLE, images named as 01_sfm/frames)",
           "world": "stage 01's world frame (CONTRACTS.md): the scene's cameras.json frame when given, the "
                    "static camera's (x right, y down, z forward), or structure from motion's (its own units)"}
    (tmp / "export.json").write_text(json.dumps(doc, indent=2) + "\n")
    shutil.rmtree(out, ignore_errors=True)
    tmp.rename(out)
    return out
