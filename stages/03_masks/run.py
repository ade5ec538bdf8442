"""Stage 03: depth-ordered person masks and occluder masks, per frame with a camera.

Inputs:  the scene (humans/<pid>/masks/ when given), 01_sfm/ (frames, cameras.json, report.json),
         02_smpl_fit/humans/<pid>/body.npz.
Params:  03_masks, body, compute (pipeline.yaml).
Outputs (OUT/<scene>/03_masks/, CONTRACTS.md):
  masks/<pid>/<frame>.png       the visible part of each person (0/255)
  masks/union/<frame>.png       every person's visible pixels
  occluders/<pid>/<frame>.png   pixels of the person's projected body, dilated, that something else hides
  masks.json                    glimpse-masks/1: mode, depth order per frame, IoU against the scene's masks
Modes: provided (the scene's masks), body (from the fitted bodies and static-scene evidence): glimpse/masks/.
"""

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from glimpse.body.models import BodyModels  # noqa: E402
from glimpse.body.params import read_body_params  # noqa: E402
from glimpse.compute import apply_compute  # noqa: E402
from glimpse.io.cameras_json import read_cameras_json  # noqa: E402
from glimpse.masks.stage import MASKS_FORMAT, MasksInputs, compute_masks  # noqa: E402
from glimpse.pipeline.runner import StageContext, stage_main  # noqa: E402
from glimpse.scene import load_scene  # noqa: E402

STAGE = "03_masks"


def run(ctx: StageContext) -> None:
    config = ctx.section(STAGE)
    body = ctx.section("body")
    apply_compute(ctx.section("compute"))
    scene = load_scene(ctx.scene_root, checked=True)
    sfm, fits = ctx.upstream_dir("01_sfm"), ctx.upstream_dir("02_smpl_fit")
    _, _, cameras = read_cameras_json(sfm / "cameras.json")
    camera_motion = json.loads((sfm / "report.json").read_text())["camera_motion"]
    import torch

    models = BodyModels.load(body, dtype=torch.float64)
    bodies = {pid: read_body_params(fits / "humans" / pid / "body.npz") for pid in scene.humans}
    inputs = MasksInputs(scene, models, cameras, bodies, sfm / "frames", camera_motion)
    with ctx.timed("masks"):
        doc = compute_masks(inputs, config, ctx.out)
    (ctx.out / "masks.json").write_text(json.dumps(doc, indent=1) + "\n")
    ctx.formats["masks.json"] = MASKS_FORMAT
    ctx.formats["masks/"] = ctx.formats["occluders/"] = "png (0/255)"
    ctx.summary["mode"] = doc["mode"]
    ctx.summary["static_scene"] = doc["static_scene"]
    if "iou_vs_scene_masks" in doc:
        ctx.summary["iou_vs_scene_masks"] = doc["iou_vs_scene_masks"]


if __name__ == "__main__":
    stage_main(STAGE, run, __doc__)
