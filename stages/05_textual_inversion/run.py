"""Stage 05: per-person crops (image, soft mask, OpenPose-18 skeleton, view prompt) for the identity prior.

Inputs:  01_sfm/ (frames, cameras.json), 02_smpl_fit/humans/<pid>/body.npz, 03_masks/masks/<pid>/.
Params:  05_textual_inversion, prior, body, compute (pipeline.yaml).
Outputs (OUT/<scene>/05_textual_inversion/, CONTRACTS.md):
  <pid>/crops/images/<frame>.png     the person cropped square, background a random colour per crop (RGB)
  <pid>/crops/masks/<frame>.png      its soft mask (0-255): eroded, feathered
  <pid>/crops/skeletons/<frame>.png  OpenPose-18 drawing of its posed body (ControlNet's convention)
  <pid>/crops/crops.json             glimpse-crops/1: per crop the frame, box, view, azimuth, prompt, keypoints
  <pid>/identity/identity.safetensors  prior.kind sds only: the person's token embedding and cross-attention K/V
  <pid>/identity/samples.png         prior.kind sds only: samples of the personalised model
Identity: trained only with prior.kind sds (needs diffusion.sd_path and diffusion.controlnet_path, and CUDA
unless diffusion.allow_cpu); any other prior skips it and the manifest's summary says so. Method:
docs/crops.md, docs/diffusion.md, glimpse/crops/, glimpse/prior/sds/.
"""

import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from glimpse.body.models import BodyModels  # noqa: E402
from glimpse.body.params import read_body_params  # noqa: E402
from glimpse.compute import apply_compute, resolve_device  # noqa: E402
from glimpse.crops.stage import CROPS_FORMAT, CropsInputs, identity_plan, person_summary, write_crops  # noqa: E402
from glimpse.io.cameras_json import read_cameras_json  # noqa: E402
from glimpse.pipeline.runner import StageContext, stage_main  # noqa: E402
from glimpse.prior.sds.load import (  # noqa: E402
    check_sds_can_run, diffusion_ready, load_diffusion,
)
from glimpse.prior.sds.person_identity import identity_formats, train_identities  # noqa: E402
from glimpse.scene import load_scene  # noqa: E402

STAGE = "05_textual_inversion"


def run(ctx: StageContext) -> None:
    config = ctx.section(STAGE)
    compute = ctx.section("compute")
    diffusion, device = ctx.section("diffusion"), resolve_device(compute)
    plan = identity_plan(ctx.section("prior").kind, diffusion_ready(diffusion, device))
    apply_compute(compute)
    if plan.identity == "trained":  # before any work: missing weights or no CUDA stop the stage here
        check_sds_can_run(diffusion, device)
    scene = load_scene(ctx.scene_root, checked=True)
    sfm, fits, masks = ctx.upstream_dir("01_sfm"), ctx.upstream_dir("02_smpl_fit"), ctx.upstream_dir("03_masks")
    _, _, cameras = read_cameras_json(sfm / "cameras.json")
    models = BodyModels.load(ctx.section("body"), dtype=torch.float64)
    pids = sorted(scene.humans)
    bodies = {pid: read_body_params(fits / "humans" / pid / "body.npz") for pid in pids}
    inputs = CropsInputs(pids, models, cameras, bodies, sfm / "frames", masks / "masks")
    with ctx.timed("crops"):
        docs = write_crops(inputs, config, compute.seed, ctx.out)
    for pid in pids:
        ctx.formats[f"{pid}/crops/crops.json"] = CROPS_FORMAT
        ctx.formats[f"{pid}/crops/images/"] = "png (RGB)"
        ctx.formats[f"{pid}/crops/masks/"] = "png (0-255 soft mask)"
        ctx.formats[f"{pid}/crops/skeletons/"] = "png (RGB, OpenPose-18 drawing)"
    ctx.summary["people"] = {pid: person_summary(docs[pid], config.min_mask_px) for pid in pids}
    if plan.identity == "trained":
        with ctx.timed("identity"):
            references = {pid: scene.humans[pid].references for pid in pids}
            summaries = train_identities(load_diffusion(diffusion, device), docs, references,
                                         config.identity, compute.seed, ctx.out)
        for pid, summary in summaries.items():
            ctx.summary["people"][pid]["identity"] = summary
        ctx.formats.update(identity_formats(ctx.out, pids))
    ctx.summary["prior_kind"] = plan.prior_kind
    ctx.summary["identity"] = plan.identity
    ctx.summary["identity_reason"] = plan.reason


if __name__ == "__main__":
    stage_main(STAGE, run, __doc__)
