"""Stage 04 (background pre-optimisation) on the fixtures: quality and speed.

Quality: for each scenario, stages 01-03 (the scene's body parameters; masks computed from the
bodies and frames, not the scene's), then stage 04 with its default schedule; the background is judged against the place rendered without people by the mesh
renderer (glimpse.background.truth): PSNR where no person is ("visible"), behind people where
the stage reports the background seen (a baked-in person, a ghost, scores what the input frame
scores there: "frame behind"), and the recall of truly never-seen pixels (static cameras).

Speed: iterations per second of the stage's training loop (2 threads), at full size on a short
schedule unless --full, as a ratio to one forward+backward render of the final Gaussians by
the rasterizer alone, measured in the same run (the rest is the loss, Adam and density control).

    .venv/bin/python bench/background.py [--full] [--scenarios demo,moving_camera]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from glimpse.background.truth import judge_background, stage_render_settings  # noqa: E402
from glimpse.cameras.model import render_camera  # noqa: E402
from glimpse.fixtures.scenes import make_scene  # noqa: E402
from glimpse.gaussians.model import GaussianModel  # noqa: E402
from glimpse.gaussians.ply import read_gaussians_ply  # noqa: E402
from glimpse.io.cameras_json import read_cameras_json  # noqa: E402
from glimpse.render import rasterize  # noqa: E402
from tests.stage_helpers import read_json, run  # noqa: E402

THREADS = 2
SEED = 0
SCENARIOS = ("demo", "lower_body_occluded", "moving_camera", "crowd")
SPEED_SCHEDULE = 0.02  # schedule_scale of the full-size speed runs without --full (600 iterations)
RENDER_REPEATS = 5


def render_seconds(stage_dir: Path, sfm_dir: Path) -> float:
    """Median seconds of one forward+backward render of the final background from the first input view."""
    model = GaussianModel.from_splats(read_gaussians_ply(stage_dir / "background.ply")[0])
    width, height, cameras = read_cameras_json(sfm_dir / "cameras.json")
    camera = render_camera(cameras[min(cameras)], torch.device("cpu"))
    times = []
    for _ in range(RENDER_REPEATS):
        started = time.perf_counter()
        out = rasterize(camera, **model.render_inputs(), settings=stage_render_settings(stage_dir))
        out.rgb.sum().backward()
        times.append(time.perf_counter() - started)
        model.zero_grad()
    return statistics.median(times)


def bench_scene(scenario: str, size: str, root: Path, params: str) -> dict:
    scene = make_scene(scenario, root / f"{scenario}_{size}", size, seed=SEED)
    out = root / "out"
    for stage in ("01_sfm", "02_smpl_fit", "03_masks"):
        run(stage, scene, out, "02_smpl_fit.overlay=false 03_masks.mode=body")
    stage_dir = run("04_bg_pretrain", scene, out, params)
    report = read_json(stage_dir / "report.json")
    run_dir = stage_dir.parent
    static = read_json(run_dir / "01_sfm" / "report.json")["camera_motion"] == "static"
    row = {"scenario": scenario, "size": size, "init": read_json(stage_dir / "init.json")["kind"], **report,
           **judge_background(stage_dir, run_dir / "01_sfm", scene, static)}
    row["render_s"] = render_seconds(stage_dir, run_dir / "01_sfm")
    return row


def _fmt(value, spec: str = ".2f") -> str:
    return "-" if value is None else format(value, spec)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--full", action="store_true", help="quality at full size with the default schedule (long)")
    parser.add_argument("--scenarios", default=",".join(SCENARIOS))
    parser.add_argument("--no-speed", action="store_true", help="skip the full-size speed runs")
    args = parser.parse_args()
    torch.set_num_threads(THREADS)
    scenarios = args.scenarios.split(",")
    cache = Path(os.environ.get("GLIMPSE_CACHE", Path.home() / ".cache" / "glimpse")) / "bench_background"
    cache.mkdir(parents=True, exist_ok=True)
    quality_size = "full" if args.full else "small"
    with tempfile.TemporaryDirectory(dir=cache) as tmp:
        quality = [bench_scene(s, quality_size, Path(tmp) / "quality", "") for s in scenarios]
        speed = quality if args.full else [
            bench_scene(s, "full", Path(tmp) / "speed", f"04_bg_pretrain.schedule_scale={SPEED_SCHEDULE}")
            for s in scenarios if s in ("demo", "moving_camera") and not args.no_speed]
    print(f"\n### quality: {quality_size} fixtures, default schedule\n")
    print("| scenario | init | iterations | Gaussians | PSNR vs frames, background px | PSNR vs empty place: visible | "
          "behind people | frame behind people | visible but reported never seen | never seen: truth / reported / "
          "recall |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in quality:
        never = (f"{r['never_seen_truth_fraction']:.3f} / {r['never_seen_reported_fraction']:.3f} / "
                 f"{_fmt(r['never_seen_recall'])}" if "never_seen_truth_fraction" in r else "- (moving camera)")
        print(f"| {r['scenario']} | {r['init']} | {r['iterations']} | {r['gaussians']} | {_fmt(r['psnr_background_db'])} | "
              f"{_fmt(r['psnr_visible_db'])} | {_fmt(r['psnr_behind_people_db'])} | "
              f"{_fmt(r['psnr_frame_behind_people_db'])} | {r['visible_reported_never_seen_fraction']:.3f} | {never} |")
    if not speed:
        return 0
    print(f"\n### speed: full-size fixtures (320x240), {THREADS} threads\n")
    print("| scenario | iterations | Gaussians at the end | iterations/s | ms/iteration | render fwd+bwd ms | "
          "iteration / render |")
    print("|---|---|---|---|---|---|---|")
    for r in speed:
        per_iteration = 1.0 / r["iterations_per_s"]
        print(f"| {r['scenario']} | {r['iterations']} | {r['gaussians']} | {r['iterations_per_s']:.1f} | "
              f"{per_iteration * 1e3:.0f} | {r['render_s'] * 1e3:.0f} | {per_iteration / r['render_s']:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
