"""Stage 02: body parameters of each person per frame, in the stage-01 world frame.

Inputs:  the scene (humans/<pid>/smpl.npz, keypoints3d.npz, keypoints2d.npz), 01_sfm/cameras.json.
Params:  02_smpl_fit, body, compute (pipeline.yaml).
Outputs (OUT/<scene>/02_smpl_fit/, CONTRACTS.md):
  humans/<pid>/body.npz         glimpse-body-params/1 (betas, global_orient, body_pose, transl, scale, ...)
  humans/<pid>/fit_report.json  glimpse-fit-report/1: mode, per-frame keypoint residuals (world units, pixels)
Modes per person: provided (built); keypoints3d and keypoints2d fitting arrive with the rest of issue #7.
"""

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from glimpse.body.config import BodyConfig, resolve_model_path  # noqa: E402
from glimpse.body.model import BodyModel  # noqa: E402
from glimpse.body.params import BODY_PARAMS_FORMAT, write_body_params  # noqa: E402
from glimpse.compute import ComputeConfig, apply_compute  # noqa: E402
from glimpse.config import config_from_mapping  # noqa: E402
from glimpse.fit.config import FitConfig  # noqa: E402
from glimpse.fit.stage import fit_person  # noqa: E402
from glimpse.io.cameras_json import read_cameras_json  # noqa: E402
from glimpse.pipeline.runner import StageContext, stage_main  # noqa: E402
from glimpse.scene import load_scene  # noqa: E402

STAGE = "02_smpl_fit"


def run(ctx: StageContext) -> None:
    config = config_from_mapping(FitConfig, ctx.params[STAGE], f"pipeline.yaml {STAGE}")
    body = config_from_mapping(BodyConfig, ctx.params["body"], "pipeline.yaml body")
    apply_compute(config_from_mapping(ComputeConfig, ctx.params["compute"], "pipeline.yaml compute"))
    scene = load_scene(ctx.scene_root)
    _, _, cameras = read_cameras_json(ctx.upstream_dir("01_sfm") / "cameras.json")
    import torch

    model = BodyModel.from_file(resolve_model_path(body), dtype=torch.float64)
    modes = {}
    for pid, person in sorted(scene.humans.items()):
        with ctx.timed(f"fit_{pid}"):
            fit = fit_person(scene, person, model, cameras, config)
        folder = ctx.out / "humans" / pid
        folder.mkdir(parents=True)
        write_body_params(folder / "body.npz", fit.params)
        (folder / "fit_report.json").write_text(json.dumps(fit.report, indent=1) + "\n")
        ctx.formats[f"humans/{pid}/body.npz"] = BODY_PARAMS_FORMAT
        ctx.formats[f"humans/{pid}/fit_report.json"] = fit.report["format"]
        modes[pid] = fit.mode
    ctx.summary["modes"] = modes


if __name__ == "__main__":
    stage_main(STAGE, run, __doc__)
