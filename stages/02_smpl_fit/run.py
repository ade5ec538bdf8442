"""Stage 02: body parameters of each person per frame, in the stage-01 world frame.

Inputs:  the scene (humans/<pid>/smpl.npz, keypoints3d.npz, keypoints2d.npz; frames for the overlay),
         01_sfm/cameras.json and report.json (units).
Params:  02_smpl_fit, body, compute (pipeline.yaml).
Outputs (OUT/<scene>/02_smpl_fit/, CONTRACTS.md):
  humans/<pid>/body.npz         glimpse-body-params/1 (betas, global_orient, body_pose, transl, scale, interpolated)
  humans/<pid>/fit_report.json  glimpse-fit-report/2: mode, fit stages, per-frame keypoint residuals (m, px)
  ground.json                   glimpse-ground/1: the people's common floor and each one's placement factor
  overlay.mp4                   the fitted bodies over the input frames (02_smpl_fit.overlay)
Modes per person: provided > keypoints3d > keypoints2d unless 02_smpl_fit.mode forces one (glimpse/fit/).
"""

import json
import sys
from pathlib import Path


sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from glimpse.body.models import BodyModels  # noqa: E402
from glimpse.body.params import BODY_PARAMS_FORMAT, write_body_params  # noqa: E402
from glimpse.compute import apply_compute  # noqa: E402
from glimpse.fit.stage import GROUND_FORMAT, Fitter  # noqa: E402
from glimpse.fit.video import write_overlay_video  # noqa: E402
from glimpse.io.cameras_json import read_cameras_json  # noqa: E402
from glimpse.io.progress import progress  # noqa: E402
from glimpse.pipeline.runner import StageContext, stage_main  # noqa: E402
from glimpse.scene import load_scene  # noqa: E402

STAGE = "02_smpl_fit"


def run(ctx: StageContext) -> None:
    config = ctx.section(STAGE)
    body = ctx.section("body")
    apply_compute(ctx.section("compute"))
    scene = load_scene(ctx.scene_root, checked=True)
    cameras_dir = ctx.upstream_dir("01_sfm")
    _, _, cameras = read_cameras_json(cameras_dir / "cameras.json")
    units = json.loads((cameras_dir / "report.json").read_text())["units"]
    import torch

    models = BodyModels.load(body, dtype=torch.float64)
    fitter = Fitter(scene, models, cameras, config, units)
    people = [person for _, person in sorted(scene.humans.items())]
    with ctx.timed("fit"):
        fits, floor = fitter.fit_people(people, progress=lambda items: progress(items, desc="02_smpl_fit people",
                                                                            unit="person"))
    for fit in fits:
        folder = ctx.out / "humans" / fit.pid
        folder.mkdir(parents=True)
        write_body_params(folder / "body.npz", fit.params)
        (folder / "fit_report.json").write_text(json.dumps(fit.report, indent=1) + "\n")
        ctx.formats[f"humans/{fit.pid}/body.npz"] = BODY_PARAMS_FORMAT
        ctx.formats[f"humans/{fit.pid}/fit_report.json"] = fit.report["format"]
    (ctx.out / "ground.json").write_text(json.dumps({"format": GROUND_FORMAT, **floor}, indent=1) + "\n")
    ctx.formats["ground.json"] = GROUND_FORMAT
    if config.overlay:
        with ctx.timed("overlay"):
            keypoints = {pid: kp for pid, person in scene.humans.items()
                         if (kp := fitter.image_keypoints(person)) is not None}
            write_overlay_video(ctx.out / "overlay.mp4", scene, models, cameras, fits, cameras_dir / "frames",
                                keypoints)
        ctx.formats["overlay.mp4"] = "mp4/h264"
    ctx.summary["modes"] = {fit.pid: fit.mode for fit in fits}
    ctx.summary["ground"] = {k: floor[k] for k in ("applied", "reason", "camera_height", "camera_height_from", "factors",
                                                    "stated_not_used") if k in floor}
    ctx.summary["keypoint_residuals"] = {
        fit.pid: {k: v["mean"] for k, v in fit.report.items() if k.endswith(("_residual_m", "_residual_px")) and v}
        for fit in fits}


if __name__ == "__main__":
    stage_main(STAGE, run, __doc__)
