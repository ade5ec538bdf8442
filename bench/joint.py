"""Stage 06 (joint optimisation, prior none) on the fixtures: held-out quality and speed.

Quality (--quality): for each scenario at full size (320x240, 100 frames), stages 01-03 with
bodies fitted to the scene's keypoints (--fit keypoints3d, the default, or keypoints2d: never the
ground-truth parameters unless --fit provided) and masks from the bodies and frames, stage 04,
stage 06 with its default schedule, then stage 07
on the held-out cameras (ground truth rendered by the mesh renderer): humans-only PSNR / SSIM /
LPIPS (GTU's protocol), per person inside their own masks, and the full composite.

Speed (default): iterations per second of stage 06's training loop (2 threads) at small and full
size on a short schedule, as a ratio to one forward+backward render of the same Gaussians
(background and people posed), posing and rasterizer only, measured in the same run.

    .venv/bin/python bench/joint.py [--quality] [--scenarios demo,sparse] [--fit keypoints2d] [--seed 1]
                                    [--bg-schedule 0.02] [--no-speed]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from glimpse.background.stage import render_camera  # noqa: E402
from glimpse.body.model import BodyModel  # noqa: E402
from glimpse.fixtures.scenes import make_scene  # noqa: E402
from glimpse.gaussians.model import GaussianModel  # noqa: E402
from glimpse.gaussians.ply import read_gaussians_ply  # noqa: E402
from glimpse.humans.load import load_trained_people  # noqa: E402
from glimpse.io.cameras_json import read_cameras_json  # noqa: E402
from glimpse.joint.compose import frame_gaussians, render_frame  # noqa: E402
from glimpse.render.config import RenderConfig  # noqa: E402
from tests.stage_helpers import read_json, run  # noqa: E402

THREADS = 2
SEED = 0
QUALITY_SCENARIOS = ("demo", "lower_body_occluded", "sparse", "crowd", "moving_camera")
SPEED_SIZES = ("small", "full")
SPEED_SCHEDULE = 0.02  # schedule_scale of stage 06 in the speed runs (240 iterations, densification included)
SPEED_BG_SCHEDULE = 0.02  # schedule_scale of stage 04 before the speed runs
UPSTREAM_PARAMS = "02_smpl_fit.overlay=false 03_masks.mode=body"  # plus 02_smpl_fit.mode from --fit
RENDER_REPEATS = 5
RENDER = RenderConfig("auto", 2, False)


def render_seconds(run_dir: Path) -> tuple[float, int]:
    """Median seconds of one forward+backward render of stage 06's final Gaussians (background and every
    person present) from the first input view, and how many Gaussians that render has."""
    model = GaussianModel.from_splats(read_gaussians_ply(run_dir / "06_joint_opt" / "background.ply")[0])
    people = load_trained_people(run_dir / "06_joint_opt" / "humans",
                                 BodyModel.from_file(Path(__file__).resolve().parents[1] /
                                                     "glimpse/body/assets/free_body.npz"))
    width, height, cameras = read_cameras_json(run_dir / "01_sfm" / "cameras.json")
    frame = min(f for f in cameras if any(p.in_frame(f) for p in people))
    camera = render_camera(cameras[frame], width, height, torch.device("cpu"))
    times, count = [], 0
    for _ in range(RENDER_REPEATS):
        started = time.perf_counter()
        gaussians = frame_gaussians(camera, frame, people, RENDER.sh_degree, model, RENDER.sh_degree)
        render_frame(camera, gaussians, len(people), RENDER).rgb.sum().backward()
        times.append(time.perf_counter() - started)
        count = len(gaussians.means)
        model.zero_grad()
        for person in people:
            person.zero_grad()
    return statistics.median(times), count


def run_scene(scenario: str, size: str, root: Path, fit: str, bg_schedule: float | None, joint_params: str,
              seed: int = SEED) -> Path:
    """Stages 01-07 on a fresh fixture scene; returns its run folder."""
    scene = make_scene(scenario, root / f"{scenario}_{size}_{fit}_{seed}", size, seed=seed)
    out = root / f"out_{fit}_{seed}"
    params = f"{UPSTREAM_PARAMS} 02_smpl_fit.mode={fit}"
    params += f" 04_bg_pretrain.schedule_scale={bg_schedule}" if bg_schedule else ""
    for stage in ("01_sfm", "02_smpl_fit", "03_masks", "04_bg_pretrain", "05_textual_inversion", "06_joint_opt",
                  "07_eval"):
        run(stage, scene, out, f"{params} {joint_params}")
    return out / f"{scenario}_{size}"


def quality(scenarios: list[str], root: Path, fit: str, bg_schedule: float | None, seed: int, params: str) -> None:
    print(f"bodies fitted with 02_smpl_fit.mode={fit}; seed {seed}; stage 04 schedule_scale "
          f"{bg_schedule or 'default'}; other parameters: {params or 'pipeline.yaml'}\n")
    print("| scenario | views | humans PSNR | SSIM | LPIPS x100 | per person PSNR (own mask) | composite PSNR | "
          "input-view PSNR, people px | Gaussians per person | iterations | it/s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for scenario in scenarios:
        run_dir = run_scene(scenario, "full", root, fit, bg_schedule, params, seed)
        metrics = read_json(run_dir / "07_eval" / "metrics.json")
        report = read_json(run_dir / "06_joint_opt" / "report.json")
        humans = metrics["tables"]["humans"]["rows"][0]
        people = metrics["tables"].get("people", {"rows": []})["rows"]
        per_person = ", ".join(f"{r['label']} {r['psnr']:.1f}" for r in people)
        composite = metrics["tables"]["composite"]["rows"][0]
        counts = ", ".join(str(p["gaussians"]) for p in report["people"].values())
        print(f"| {scenario} | {metrics['views'].split(' (')[0]} | {humans['psnr']:.2f} | {humans['ssim']:.4f} | "
              f"{humans['lpips']:.2f} | {per_person} | {composite['psnr']:.2f} | {report['psnr_people_db']} | "
              f"{counts} | {report['iterations']} | {report['iterations_per_s']:.2f} |", flush=True)


def speed(root: Path) -> None:
    print(f"| size | iterations | Gaussians in a render (background + people) | iterations/s | ms/iteration | "
          f"posing + render fwd+bwd ms | iteration / (posing + render) |")
    print("|---|---|---|---|---|---|---|")
    for size in SPEED_SIZES:
        run_dir = run_scene("demo", size, root, "keypoints3d", SPEED_BG_SCHEDULE,
                            f"06_joint_opt.schedule_scale={SPEED_SCHEDULE}")
        report = read_json(run_dir / "06_joint_opt" / "report.json")
        render_s, count = render_seconds(run_dir)
        per_iteration = 1.0 / report["iterations_per_s"]
        print(f"| {size} | {report['iterations']} | {count} | {report['iterations_per_s']:.2f} | "
              f"{per_iteration * 1e3:.0f} | {render_s * 1e3:.0f} | {per_iteration / render_s:.2f} |", flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quality", action="store_true", help="the held-out quality table (long: full size)")
    parser.add_argument("--scenarios", default=",".join(QUALITY_SCENARIOS))
    parser.add_argument("--fit", default="keypoints3d", choices=("keypoints3d", "keypoints2d", "provided"),
                        help="how stage 02 gets the bodies (provided = the ground truth)")
    parser.add_argument("--seed", type=int, default=SEED, help="the fixture scenes' seed")
    parser.add_argument("--no-speed", action="store_true", help="skip the speed runs")
    parser.add_argument("--params", default="", help="parameter overrides of the quality runs, as make's PARAMS")
    parser.add_argument("--bg-schedule", type=float, default=None,
                        help="stage 04's schedule_scale in the quality runs (default: pipeline.yaml's)")
    args = parser.parse_args()
    torch.set_num_threads(THREADS)
    with tempfile.TemporaryDirectory() as tmp:
        if args.quality:
            print("### stage 06, prior none: held-out quality at full size, bodies fitted to keypoints\n")
            quality(args.scenarios.split(","), Path(tmp), args.fit, args.bg_schedule, args.seed, args.params)
        if not args.no_speed:
            print(f"\n### stage 06 speed on demo ({THREADS} threads, schedule_scale {SPEED_SCHEDULE})\n")
            speed(Path(tmp) / "speed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
