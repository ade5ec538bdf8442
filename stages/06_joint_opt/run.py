"""Stage 06: every person's canonical Gaussians and the background, optimised jointly on the input frames.

Inputs:  01_sfm/ (frames, cameras.json), 02_smpl_fit/humans/<pid>/body.npz, 03_masks/ (masks/union/,
         occluders/<pid>/), 04_bg_pretrain/background.ply; 05_textual_inversion/ (used by the sds prior).
Params:  06_joint_opt, prior, prior_surface, body, render, compute (pipeline.yaml).
Outputs (OUT/<scene>/06_joint_opt/, CONTRACTS.md):
  humans/<pid>/canonical.ply   the person's Gaussians in the canonical (Da-pose) body frame, 3DGS layout
  humans/<pid>/skinning.npz    glimpse-skinning/1: skin-weight grid, its bounds and resolution
  humans/<pid>/body.npz        glimpse-body-params/1: the body parameters with the refined poses
  humans/<pid>/visibility.npz  glimpse-visibility/1: per body vertex, how many input frames saw it, the most
                               head-on cosine and the finest pixels per metre (stage 02's bodies)
  background.ply               the background Gaussians after joint training (same count as stage 04's)
  report.json                  glimpse-joint-report/1: prior used, losses, Gaussian counts, densification,
                               per-frame PSNR on the input views, iterations per second
  renders/joint.mp4            each input frame beside its render
  sds_previews/<pid>/<iteration>.png  prior sds with diffusion.preview_every > 0: the SDS render, its skeleton
                               and the decoded one-step denoised guess, side by side
Checkpoints: OUT/<scene>/.work/06_joint_opt/checkpoint.pt; a killed run resumes from there.
"""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from glimpse.body.models import BodyModels  # noqa: E402
from glimpse.body.params import BODY_PARAMS_FORMAT, read_body_params, write_body_params  # noqa: E402
from glimpse.body.skinning import SKINNING_FORMAT  # noqa: E402
from glimpse.compute import apply_compute, resolve_device  # noqa: E402
from glimpse.gaussians.model import GaussianModel  # noqa: E402
from glimpse.gaussians.ply import GAUSSIANS_FORMAT, read_gaussians_ply, write_gaussians_ply  # noqa: E402
from glimpse.humans.visibility import VISIBILITY_FORMAT  # noqa: E402
from glimpse.io.cameras_json import read_cameras_json  # noqa: E402
from glimpse.io.checkpoint import fingerprint  # noqa: E402
from glimpse.io.frame_cache import FrameCacheSize  # noqa: E402
from glimpse.io.json_file import write_json  # noqa: E402
from glimpse.joint.stage import JointInputs, train_joint  # noqa: E402
from glimpse.pipeline.runner import StageContext, stage_main  # noqa: E402
from glimpse.prior import PRIORS, check_prior_kind  # noqa: E402
from glimpse.prior.sds.load import check_sds_can_run, diffusion_ready  # noqa: E402
from glimpse.scene import load_scene  # noqa: E402

STAGE = "06_joint_opt"
UPSTREAM = ("01_sfm", "02_smpl_fit", "03_masks", "04_bg_pretrain", "05_textual_inversion")


def run(ctx: StageContext) -> None:
    config, render, body, compute = (ctx.section(name) for name in (STAGE, "render", "body", "compute"))
    diffusion, device = ctx.section("diffusion"), resolve_device(compute)
    prior_kind = check_prior_kind(ctx.section("prior").kind, diffusion_ready(diffusion, device))
    if prior_kind == "sds":  # before any work: missing weights or no CUDA stop the stage here
        check_sds_can_run(diffusion, device)
    apply_compute(compute)
    scene = load_scene(ctx.scene_root, checked=True)
    dirs = {name: ctx.upstream_dir(name) for name in UPSTREAM}
    width, height, cameras = read_cameras_json(dirs["01_sfm"] / "cameras.json")
    splats, _ = read_gaussians_ply(dirs["04_bg_pretrain"] / "background.ply")
    bodies = {pid: read_body_params(dirs["02_smpl_fit"] / "humans" / pid / "body.npz") for pid in scene.humans}
    inputs = JointInputs(cameras, width, height, dirs["01_sfm"] / "frames", dirs["03_masks"] / "masks",
                         dirs["03_masks"] / "occluders", bodies, GaussianModel.from_splats(splats), scene.fps)
    body_models = BodyModels.load(body)
    key = fingerprint(ctx.params, [(d / "manifest.json").read_text() for d in dirs.values()])
    section = PRIORS[prior_kind].section
    with ctx.timed("train"):
        result = train_joint(inputs, config, render, body, body_models, prior_kind,
                             ctx.section(section) if section else None, compute.seed, device,
                             FrameCacheSize(compute.frame_cache, compute.frame_read_ahead,
                                            compute.lpips_target_cache_mb), ctx.work, key, ctx.out,
                             dirs["05_textual_inversion"])
    for person in result.people:
        folder = ctx.out / "humans" / person.pid
        folder.mkdir(parents=True, exist_ok=True)
        write_gaussians_ply(folder / "canonical.ply", person.model.to_splats(),
                            {"sh_degree": str(person.model.sh_degree), "stage": STAGE, "pid": person.pid,
                             "frame": "canonical", "canonical_hip_angle_deg": str(body.canonical_hip_angle_deg)})
        np.savez(folder / "skinning.npz", **person.grid.to_npz_dict(), resolution=np.array(person.grid.resolution))
        write_body_params(folder / "body.npz", person.refined_body())
        result.visibility[person.pid].write(folder / "visibility.npz")
        ctx.formats.update({f"humans/{person.pid}/canonical.ply": GAUSSIANS_FORMAT,
                            f"humans/{person.pid}/skinning.npz": SKINNING_FORMAT,
                            f"humans/{person.pid}/body.npz": BODY_PARAMS_FORMAT,
                            f"humans/{person.pid}/visibility.npz": VISIBILITY_FORMAT})
    write_gaussians_ply(ctx.out / "background.ply", result.background.to_splats(),
                        {"sh_degree": str(result.background.sh_degree), "stage": STAGE})
    write_json(ctx.out / "report.json", result.report)
    ctx.formats.update({"background.ply": GAUSSIANS_FORMAT, "report.json": result.report["format"]})
    if config.render_video:
        ctx.formats["renders/joint.mp4"] = "mp4 (H.264)"
    ctx.summary.update({key: result.report[key] for key in (
        "prior", "iterations", "iterations_per_s", "psnr_db", "psnr_people_db", "resumed_from_iteration")})
    ctx.summary["gaussians"] = {pid: doc["gaussians"] for pid, doc in result.report["people"].items()}


if __name__ == "__main__":
    stage_main(STAGE, run, __doc__)
