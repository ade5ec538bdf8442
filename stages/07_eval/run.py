"""Stage 07: metrics of stage 06's reconstruction on held-out views, and the standard videos (renders, edits).

Inputs:  01_sfm/ (frames, cameras.json, report.json), 03_masks/masks/ (the people's mean colours; the ground
         truth when scoring the input view), 04_bg_pretrain/never_seen/ (tinted in removed_<pid>.mp4),
         06_joint_opt/ (humans/<pid>/{canonical.ply, skinning.npz, body.npz, visibility.npz}, background.ply,
         manifest);
         the scene's eval/ (held-out cameras, ground-truth images and masks; an image of a frame the scene held
         out of its input is scored with the people posed between their neighbouring frames).
Params:  07_eval, body, render, compute (pipeline.yaml).
Outputs (OUT/<scene>/07_eval/, CONTRACTS.md):
  metrics.json   glimpse-eval-metrics/1: tables "humans" (GTU's protocol: people only on black against the
                 ground truth masked by the union human mask), "people" (each person inside their own mask),
                 "seen" and "never_seen" (humans only, restricted to the body surface some input frame saw, and
                 to the rest), "composite" (the whole frame); baselines (empty render, bodies in mean colour)
                 in the humans, seen and never-seen tables, the flat bodies in the people table; per-view
                 values and each table's protocol
  metrics.md     the same tables in Markdown, each followed by its protocol
  renders/       input.mp4, heldout_<camera>.mp4, orbit.mp4, freeze.mp4, person_<pid>.mp4, removed_<pid>.mp4,
                 motion_<pid>.mp4 (glimpse/eval/renders.py; 07_eval.renders)
  speed.json     glimpse-speed/1: novel-pose frames per second of each person at each size, and of the whole
                 scene at the input resolution, with peak memory (glimpse/eval/speed.py; 07_eval.speed)
  speed.md       the same as Markdown tables
Then, beside the stage folders: OUT/<scene>/report.html and report_files/, the run report (glimpse/report/;
section report; refreshed by `glimpse report RUN`).
"""

import json
import logging
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from glimpse.body.models import BodyModels  # noqa: E402
from glimpse.compute import apply_compute, resolve_device  # noqa: E402
from glimpse.config import load_pipeline_yaml  # noqa: E402
from glimpse.errors import GlimpseError  # noqa: E402
from glimpse.eval.never_seen import PosedBodies, person_mean_colours  # noqa: E402
from glimpse.eval.renders import write_render_set  # noqa: E402
from glimpse.eval.score import METRICS_FORMAT, headline, score_views, write_tables  # noqa: E402
from glimpse.eval.speed import SPEED_FORMAT, speed_markdown, speed_report  # noqa: E402
from glimpse.eval.views import choose_views  # noqa: E402
from glimpse.gaussians.model import GaussianModel  # noqa: E402
from glimpse.gaussians.ply import read_gaussians_ply  # noqa: E402
from glimpse.humans.load import load_trained_people  # noqa: E402
from glimpse.humans.visibility import BodyVisibility  # noqa: E402
from glimpse.io.cameras_json import read_cameras_json  # noqa: E402
from glimpse.metrics.lpips import LPIPS  # noqa: E402
from glimpse.pipeline.runner import StageContext, stage_main  # noqa: E402
from glimpse.replay.finished import FinishedRun  # noqa: E402
from glimpse.report.page import write_report  # noqa: E402
from glimpse.scene import load_scene  # noqa: E402

STAGE = "07_eval"
log = logging.getLogger("glimpse.07_eval")


def run(ctx: StageContext) -> None:
    config, render, body, compute = (ctx.section(name) for name in (STAGE, "render", "body", "compute"))
    apply_compute(compute)
    device = resolve_device(compute)
    scene = load_scene(ctx.scene_root, checked=True)
    sfm, masks, joint = (ctx.upstream_dir(name) for name in ("01_sfm", "03_masks", "06_joint_opt"))
    width, height, cameras = read_cameras_json(sfm / "cameras.json")
    sfm_report = json.loads((sfm / "report.json").read_text())
    world_is_scene_frame = sfm_report.get("mode") != "sfm" or scene.cameras is not None
    view_set = choose_views(config, scene, world_is_scene_frame, cameras, sfm / "frames",
                            masks / "masks")
    if not view_set.views:
        raise GlimpseError(f"07_eval: no view to score (no eval/ image and no input frame with a camera in {sfm})")
    body_models = BodyModels.load(body)
    # a held-out view may show a frame of the input video that the scene held out: people are posed there
    # between their neighbouring frames
    people = [p.to(device) for p in load_trained_people(joint / "humans", body_models,
                                                        [view.frame_id for view in view_set.views])]
    visibility = {p.pid: BodyVisibility.read(joint / "humans" / p.pid / "visibility.npz") for p in people}
    colours = person_mean_colours(sfm / "frames", masks / "masks", [p.pid for p in people], config.mean_colour_every)
    background = GaussianModel.from_splats(read_gaussians_ply(joint / "background.ply")[0]).to(device)
    prior = json.loads((joint / "manifest.json").read_text()).get("summary", {}).get("prior", "unknown")
    with ctx.timed("score"):
        tables = score_views(view_set, people, background, render, LPIPS(config.lpips_net).to(device), device,
                             PosedBodies(people, visibility, body_models), [colours[p.pid] for p in people])
    write_tables(tables, prior, view_set.description, ctx.out)
    ctx.formats.update({"metrics.json": METRICS_FORMAT, "metrics.md": "markdown"})
    finished = FinishedRun(joint.parent, width, height, cameras, background, people, body_models, render)
    if config.renders.enabled:
        heldout = view_set.views if view_set.source == "held-out" else []
        with ctx.timed("renders"):
            videos = write_render_set(finished, config.renders, heldout, sfm / "frames",
                                      ctx.upstream_dir("04_bg_pretrain") / "never_seen", scene.fps,
                                      ctx.out / "renders", device)
        ctx.formats.update({f"renders/{name}": "mp4 (H.264)" for name in videos})
        ctx.summary["renders"] = videos
    if config.speed.enabled:
        with ctx.timed("speed"):
            report = speed_report(finished, config.speed, device, lambda line: print(line, file=sys.stderr, flush=True))
        (ctx.out / "speed.json").write_text(json.dumps(report, indent=2) + "\n")
        (ctx.out / "speed.md").write_text(speed_markdown(report))
        ctx.formats.update({"speed.json": SPEED_FORMAT, "speed.md": "markdown"})
        ctx.summary["scene_fps"] = report["scene"]["fps"]
    ctx.summary.update({"views": view_set.source, "view_count": len(view_set.views), "prior": prior,
                        **headline(tables)})


def write_run_report(ctx: StageContext) -> None:
    """report.html from the published outputs. A failure is logged, not raised: the metrics and videos are
    published already, and `glimpse report RUN` writes the report again."""
    try:
        write_report(ctx.run.root, ctx.section("report"), load_pipeline_yaml(resolve_auto=False))
    except Exception:
        log.exception("the run report was not written; run `glimpse report %s` to retry", ctx.run.root)


if __name__ == "__main__":
    stage_main(STAGE, run, __doc__, write_run_report)
