"""Stage 04: background Gaussians pre-trained on the pixels no person covers.

Inputs:  01_sfm/ (frames, cameras.json, points.ply when the camera moves), 02_smpl_fit/humans/<pid>/body.npz
         (the sphere's centre), 03_masks/masks/union/.
Params:  04_bg_pretrain, render, compute (pipeline.yaml).
Outputs (OUT/<scene>/04_bg_pretrain/, CONTRACTS.md):
  background.ply              the Gaussians, standard 3DGS layout (glimpse-gaussians/1)
  init.json                   glimpse-bg-init/1: SfM points, or the sphere's centre and radius
  report.json                 glimpse-bg-report/1: PSNR on background pixels per frame, never-seen regions,
                              iterations per second, densification events, loss history
  renders/background.mp4      the background alone from each input view
  never_seen/<frame>.png      pixels whose background no input frame showed (0/255)
Checkpoints: OUT/<scene>/.work/04_bg_pretrain/checkpoint.pt; a killed run resumes from there.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from glimpse.background.stage import BackgroundInputs, train_background  # noqa: E402
from glimpse.body.params import read_body_params  # noqa: E402
from glimpse.compute import apply_compute, resolve_device  # noqa: E402
from glimpse.gaussians.ply import GAUSSIANS_FORMAT, write_gaussians_ply  # noqa: E402
from glimpse.io.cameras_json import read_cameras_json  # noqa: E402
from glimpse.io.checkpoint import fingerprint  # noqa: E402
from glimpse.io.frame_cache import FrameCacheSize  # noqa: E402
from glimpse.io.json_file import write_json  # noqa: E402
from glimpse.pipeline.runner import StageContext, stage_main  # noqa: E402
from glimpse.scene import load_scene  # noqa: E402

STAGE = "04_bg_pretrain"


def run(ctx: StageContext) -> None:
    config = ctx.section(STAGE)
    render = ctx.section("render")
    compute = ctx.section("compute")
    apply_compute(compute)
    scene = load_scene(ctx.scene_root, checked=True)
    sfm, fits, masks = ctx.upstream_dir("01_sfm"), ctx.upstream_dir("02_smpl_fit"), ctx.upstream_dir("03_masks")
    width, height, cameras = read_cameras_json(sfm / "cameras.json")
    points = sfm / "points.ply"
    inputs = BackgroundInputs(cameras, width, height, sfm / "frames", masks / "masks" / "union",
                              points if points.is_file() else None,
                              {pid: read_body_params(fits / "humans" / pid / "body.npz") for pid in scene.humans},
                              scene.fps)
    key = fingerprint(ctx.params, [(d / "manifest.json").read_text() for d in (sfm, fits, masks)])
    with ctx.timed("train"):
        frames = FrameCacheSize(compute.frame_cache, compute.frame_read_ahead, compute.lpips_target_cache_mb)
        result = train_background(inputs, config, render, compute.seed, resolve_device(compute), frames, ctx.work, key,
                                  ctx.out)
    write_gaussians_ply(ctx.out / "background.ply", result.model.to_splats(),
                        {"sh_degree": str(result.model.sh_degree), "stage": STAGE})
    write_json(ctx.out / "init.json", result.init_doc)
    write_json(ctx.out / "report.json", result.report)
    ctx.formats.update({"background.ply": GAUSSIANS_FORMAT, "init.json": result.init_doc["format"],
                        "report.json": result.report["format"], "never_seen/": "png (0/255)"})
    if config.render_video:
        ctx.formats["renders/background.mp4"] = "mp4 (H.264)"
    ctx.summary.update({key: result.report[key] for key in (
        "psnr_background_db", "iterations", "iterations_per_s", "gaussians", "gaussians_never_seen",
        "never_seen_fraction_mean", "resumed_from_iteration")})
    ctx.summary["init"] = result.init_doc["kind"]


if __name__ == "__main__":
    stage_main(STAGE, run, __doc__)
