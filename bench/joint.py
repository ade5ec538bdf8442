"""Stage 06 (joint optimisation) on the fixtures, per prior: held-out quality and speed.

Quality (--quality): for each scenario at full size (320x240, 100 frames), stages 01-03 with
bodies fitted to the scene's keypoints (--fit keypoints3d, the default, or keypoints2d: never the
ground-truth parameters unless --fit provided) and masks from the bodies and frames, stages 04-05,
then for each prior of --priors stage 06 with its default schedule and stage 07 on the held-out
cameras (ground truth rendered by the mesh renderer): humans-only PSNR / SSIM / LPIPS (GTU's
protocol) and the same restricted to the never-seen pixels, each beside the two baselines (empty
render, bodies in mean colour); per person inside their own masks; the full composite; and the
hedgehog count (Gaussians with a largest scale above HEDGEHOG_SCALE_M, or a largest / middle
scale above HEDGEHOG_RATIO) and each person's canonical holes (glimpse.eval.coverage). --pictures
DIR saves each person's canonical turntable per prior. Diagnostics: --placement-from-truth moves each fitted
person by the one similarity that best aligns its joints to the truth before stage 03: the pose as fitted,
the placement and size exact (what a 2D fit's held-out loss owes to where it put people).
--exact-keypoints fits exact keypoints instead of the fixture's noisy ones (what the noise costs).
--shape-from-truth states every person's true body shape to stage 02 (02_smpl_fit.person_shapes, as a user
who knows the shapes would): what a 2D fit's loss owes to the shape, which 2D keypoints do not carry.
--scene-scale S moves every fitted person about the camera by the factor S after stage 02 (each joint x to
c + S (x - c)): the same pixels in the input views, what a scene scale S off costs the held-out views.

Speed (default): iterations per second of stage 06's training loop (2 threads) at small and full
size on a short schedule, per prior, as a ratio to one forward+backward render of the same
Gaussians (background and people posed), posing and rasterizer only, measured in the same run;
the prior's share of an iteration is 1 - (ms per iteration with prior none) / (ms with it), same run.

    .venv/bin/python bench/joint.py [--quality] [--scenarios demo,sparse] [--priors none,surface]
                                    [--fit keypoints2d] [--seed 1] [--bg-schedule 0.02] [--no-speed]
                                    [--placement-from-truth] [--exact-keypoints] [--shape-from-truth]
                                    [--scene-scale S] [--pictures DIR] [--keep DIR]
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from glimpse.body.model import BodyModel  # noqa: E402
from glimpse.body.models import BodyModels  # noqa: E402
from glimpse.body.params import read_body_params, write_body_params  # noqa: E402
from glimpse.cameras.model import render_camera  # noqa: E402
from glimpse.eval.coverage import CoverageConfig, canonical_hole_share  # noqa: E402
from glimpse.eval.renders import canonical_turntable  # noqa: E402
from glimpse.fit.evaluate import joint_errors, moved_onto_truth, scaled_about_cameras  # noqa: E402
from glimpse.fixtures.scenes import make_scene  # noqa: E402
from glimpse.gaussians.model import GaussianModel  # noqa: E402
from glimpse.gaussians.ply import read_gaussians_ply  # noqa: E402
from glimpse.humans.compose import frame_gaussians, render_frame  # noqa: E402
from glimpse.humans.load import load_trained_people  # noqa: E402
from glimpse.io.cameras_json import read_cameras_json  # noqa: E402
from glimpse.io.images import write_png  # noqa: E402
from glimpse.render.config import RenderConfig  # noqa: E402
from tests.stage_helpers import read_json, run  # noqa: E402

from fit import degrade_keypoints, true_shape_files  # noqa: E402  (bench/fit.py, beside this file)

THREADS = 2
SEED = 0
QUALITY_SCENARIOS = ("demo", "lower_body_occluded", "sparse", "crowd", "moving_camera")
SPEED_SIZES = ("small", "full")
SPEED_SCHEDULE = 0.02  # schedule_scale of stage 06 in the speed runs (240 iterations, densification included)
SPEED_BG_SCHEDULE = 0.02  # schedule_scale of stage 04 before the speed runs
UPSTREAM_PARAMS = "02_smpl_fit.overlay=false 03_masks.mode=body"  # plus 02_smpl_fit.mode from --fit
RENDER_REPEATS = 5
RENDER = RenderConfig("auto", 2, False)
BODY_MODEL = Path(__file__).resolve().parents[1] / "glimpse/body/assets/free_body.npz"
HEDGEHOG_SCALE_M = 0.03  # metres: a human Gaussian with a larger largest scale is counted as a spike
HEDGEHOG_RATIO = 10.0  # largest / middle scale above which a human Gaussian is counted as a needle
TURNTABLE_VIEWS, TURNTABLE_PX, TURNTABLE_RADIUS_M, TURNTABLE_FOVY_DEG = 8, 160, 2.6, 49.1


def render_seconds(run_dir: Path) -> tuple[float, int]:
    """Median seconds of one forward+backward render of stage 06's final Gaussians (background and every
    person present) from the first input view, and how many Gaussians that render has."""
    model = GaussianModel.from_splats(read_gaussians_ply(run_dir / "06_joint_opt" / "background.ply")[0])
    people = trained_people(run_dir)
    width, height, cameras = read_cameras_json(run_dir / "01_sfm" / "cameras.json")
    frame = min(f for f in cameras if any(p.in_frame(f) for p in people))
    camera = render_camera(cameras[frame], torch.device("cpu"))
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


@dataclass(frozen=True)
class Diagnostics:
    """What of the truth the quality runs are given (each a command-line flag; all off: a plain run)."""

    placement_from_truth: bool = False  # each fitted person moved onto the truth by one similarity
    exact_keypoints: bool = False  # the fixture's keypoints replaced by exact ones
    shape_from_truth: bool = False  # every person's true body shape stated to stage 02
    scene_scale: float = 1.0  # every fitted person moved about the camera by this factor (1: not moved)

    def describe(self) -> str:
        """The quality table's caption words for the diagnostics on, each starting "; "."""
        return "".join(words for on, words in (
            (self.placement_from_truth, "; each moved onto the truth by one similarity (placement from truth)"),
            (self.exact_keypoints, "; exact keypoints (the fixture's noise taken out)"),
            (self.shape_from_truth, "; every person's true body shape stated (02_smpl_fit.person_shapes)"),
            (self.scene_scale != 1.0, f"; every person moved about the camera by {self.scene_scale:g} (scene scale)"))
            if on)


def run_scene(scenario: str, size: str, root: Path, fit: str, bg_schedule: float | None, joint_params: str,
              seed: int = SEED, priors: tuple[str, ...] = ("none",),
              diagnostics: Diagnostics = Diagnostics()) -> Iterator[tuple[str, Path]]:
    """Stages 01-05 on a fresh fixture scene, then 06-07 once per prior: yields (prior, run folder) after each
    (the next prior's stage 06 replaces the previous one's outputs)."""
    scene = make_scene(scenario, root / f"{scenario}_{size}_{fit}_{seed}", size, seed=seed)
    truth = scene.with_name(scene.name + ".groundtruth")
    needs_model = (diagnostics.exact_keypoints or diagnostics.placement_from_truth
                   or diagnostics.scene_scale != 1.0)  # plain runs load none
    model = BodyModel.from_file(BODY_MODEL, dtype=torch.float64) if needs_model else None
    if diagnostics.exact_keypoints:
        degrade_keypoints(scene, truth, model, "clean", np.random.default_rng(seed))
    out = root / f"out_{fit}_{seed}"
    params = f"{UPSTREAM_PARAMS} 02_smpl_fit.mode={fit}"
    params += f" 04_bg_pretrain.schedule_scale={bg_schedule}" if bg_schedule else ""
    if diagnostics.shape_from_truth:
        params += f" 02_smpl_fit.person_shapes=[{','.join(true_shape_files(truth, root / 'true_shapes'))}]"
    for stage in ("01_sfm", "02_smpl_fit", "03_masks", "04_bg_pretrain", "05_textual_inversion"):
        stage_out = run(stage, scene, out, f"{params} {joint_params}")
        if stage == "02_smpl_fit" and diagnostics.placement_from_truth:
            place_as_truth(stage_out / "humans", truth, model)
        if stage == "02_smpl_fit" and diagnostics.scene_scale != 1.0:
            scale_about_camera(stage_out / "humans", stage_out.parent / "01_sfm" / "cameras.json", model,
                               diagnostics.scene_scale)
    for prior in priors:
        kind, _, overrides = prior.partition("@")  # "surface@prior_surface.garments=false": a variant
        for stage in ("06_joint_opt", "07_eval"):
            run(stage, scene, out, f"{params} {joint_params} prior.kind={kind} {overrides.replace('@', ' ')}")
        yield prior, out / f"{scenario}_{size}"


def place_as_truth(humans: Path, truth: Path, model: BodyModel) -> None:
    """Move each person of stage 02's ``humans`` folder onto the fixture's ground truth in ``truth`` by one
    similarity (glimpse.fit.evaluate.moved_onto_truth), and print it."""
    for path in sorted(humans.glob("*/body.npz")):
        fitted, true = read_body_params(path), dict(np.load(truth / f"{path.parent.name}_body.npz"))
        moved, move = moved_onto_truth(model, fitted, true)
        write_body_params(path, moved)
        before, after = (joint_errors(model, params, true)["mpjpe_m"] for params in (fitted, moved))
        print(f"placement from truth: {path.parent.name} scaled {move.scale:.4f}, turned "
              f"{np.degrees(Rotation.from_matrix(move.rotation).magnitude()):.2f} deg, mean joint error "
              f"{before * 100:.1f} -> {after * 100:.1f} cm", flush=True)


def scale_about_camera(humans: Path, cameras_json: Path, model: BodyModel, factor: float) -> None:
    """Move each person of stage 02's ``humans`` folder about its frame's camera centre by ``factor``
    (glimpse.fit.evaluate.scaled_about_cameras): the same pixels in the input views."""
    _, _, cameras = read_cameras_json(cameras_json)
    for path in sorted(humans.glob("*/body.npz")):
        fitted = read_body_params(path)
        centres = np.stack([cameras[int(f)].centre for f in fitted.frame_ids])
        write_body_params(path, scaled_about_cameras(model, fitted, centres, factor))
        print(f"scene scale: {path.parent.name} moved about the camera by {factor:g}", flush=True)


def hedgehogs(run_dir: Path) -> tuple[int, int, int]:
    """(Gaussians of every person, those with a largest scale above HEDGEHOG_SCALE_M, those with a largest /
    middle scale above HEDGEHOG_RATIO) in stage 06's canonical people."""
    total = large = needles = 0
    for ply in sorted((run_dir / "06_joint_opt" / "humans").glob("*/canonical.ply")):
        scales = np.sort(np.exp(read_gaussians_ply(ply)[0].log_scales), axis=1)
        total += len(scales)
        large += int((scales[:, 2] > HEDGEHOG_SCALE_M).sum())
        needles += int((scales[:, 2] > HEDGEHOG_RATIO * scales[:, 1]).sum())
    return total, large, needles


def trained_people(run_dir: Path) -> list:
    """Stage 06's people of a run, loaded once for the holes and the turntables."""
    return load_trained_people(run_dir / "06_joint_opt" / "humans", BodyModels(BodyModel.from_file(BODY_MODEL)))


def hole_shares(people: list) -> str:
    """Per person, the % of their canonical body silhouette their Gaussians leave see-through (alpha < 0.5,
    glimpse.eval.coverage), e.g. "p0 2.4, p1 0.8"."""
    faces, device = BodyModel.from_file(BODY_MODEL).faces.numpy(), torch.device("cpu")
    return ", ".join(f"{p.pid} {100 * canonical_hole_share(p, faces, CoverageConfig(), RENDER, device):.1f}"
                     for p in people)


def turntables(people: list, picture: Path) -> None:
    """Every person's canonical Gaussians from TURNTABLE_VIEWS azimuths (elevation 0), one row per person."""
    rows = [np.concatenate(list(canonical_turntable(person, TURNTABLE_VIEWS, TURNTABLE_PX,
                                                    TURNTABLE_RADIUS_M, TURNTABLE_FOVY_DEG, RENDER,
                                                    torch.device("cpu"))), axis=1) for person in people]
    if rows:
        picture.parent.mkdir(parents=True, exist_ok=True)
        write_png(picture, np.concatenate(rows, axis=0))


def quality(scenarios: list[str], root: Path, fit: str, bg_schedule: float | None, seed: int, params: str,
            priors: tuple[str, ...], pictures: Path | None, diagnostics: Diagnostics = Diagnostics()) -> None:
    print(f"bodies fitted with 02_smpl_fit.mode={fit}{diagnostics.describe()}; seed {seed}; stage 04 schedule_scale "
          f"{bg_schedule or 'default'}; other parameters: {params or 'pipeline.yaml'}\n")
    print("| scenario | prior | views | humans PSNR | SSIM | LPIPS x100 | seen PSNR | SSIM | LPIPS x100 | "
          "never-seen PSNR | SSIM | LPIPS x100 | per person PSNR (own mask) | composite PSNR | input-view PSNR, "
          f"people px | Gaussians per person | > {HEDGEHOG_SCALE_M * 100:g} cm / ratio > {HEDGEHOG_RATIO:g} | "
          "canonical holes % | it/s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    baselines = []
    for scenario in scenarios:
        for prior, run_dir in run_scene(scenario, "full", root, fit, bg_schedule, params, seed, priors,
                                        diagnostics):
            metrics = read_json(run_dir / "07_eval" / "metrics.json")
            report = read_json(run_dir / "06_joint_opt" / "report.json")
            tables = metrics["tables"]
            humans = tables["humans"]["rows"]
            seen = tables.get("seen", {"rows": []})["rows"]
            unseen = tables.get("never_seen", {"rows": []})["rows"]
            people = tables.get("people", {"rows": []})["rows"]
            per_person = ", ".join(f"{r['label']} {r['psnr']:.1f}" for r in people if "baseline" not in r["label"])
            composite = tables["composite"]["rows"][0]
            counts = ", ".join(str(p["gaussians"]) for p in report["people"].values())
            total, large, needles = hedgehogs(run_dir)
            people_of_run = trained_people(run_dir)
            label = prior if "@" in prior else report["prior"]  # a variant shows its overrides
            print(f"| {scenario} | {label} | {metrics['views'].split(' (')[0]} | {humans[0]['psnr']:.2f} | "
                  f"{humans[0]['ssim']:.4f} | {humans[0]['lpips']:.2f} | {_cells(seen, 0)} | {_cells(unseen, 0)} | "
                  f"{per_person} | {composite['psnr']:.2f} | {report['psnr_people_db']} | {counts} | "
                  f"{large} / {needles} of {total} | "
                  f"{hole_shares(people_of_run)} | {report['iterations_per_s']:.2f} |", flush=True)
            if prior == priors[0]:
                baselines.append((scenario, humans[1:], seen[1:], unseen[1:]))
            if pictures is not None:
                turntables(people_of_run, pictures / f"turntable_{scenario}_{prior}.png")
    print("\nBaselines (same views and protocol):\n")
    print("| scenario | baseline | humans PSNR | SSIM | LPIPS x100 | seen PSNR | SSIM | LPIPS x100 | never-seen PSNR | "
          "SSIM | LPIPS x100 |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for scenario, humans, seen, unseen in baselines:
        for k, row in enumerate(humans):
            print(f"| {scenario} | {row['label'].removeprefix('baseline: ')} | {row['psnr']:.2f} | {row['ssim']:.4f} | "
                  f"{row['lpips']:.2f} | {_cells(seen, k)} | {_cells(unseen, k)} |")


def _cells(rows: list[dict], k: int) -> str:
    """PSNR | SSIM | LPIPS x100 of row ``k`` of a table's rows, or dashes when the table has no such row."""
    return f"{rows[k]['psnr']:.2f} | {rows[k]['ssim']:.4f} | {rows[k]['lpips']:.2f}" if k < len(rows) else "- | - | -"


def speed(root: Path, priors: tuple[str, ...]) -> None:
    print("| size | prior | iterations | Gaussians in a render (background + people) | iterations/s | ms/iteration | "
          "posing + render fwd+bwd ms | iteration / (posing + render) | prior's share of an iteration |")
    print("|---|---|---|---|---|---|---|---|---|")
    for size in SPEED_SIZES:
        without = None
        for prior, run_dir in run_scene("demo", size, root, "keypoints3d", SPEED_BG_SCHEDULE,
                                        f"06_joint_opt.schedule_scale={SPEED_SCHEDULE}", priors=priors):
            report = read_json(run_dir / "06_joint_opt" / "report.json")
            render_s, count = render_seconds(run_dir)
            per_iteration = 1.0 / report["iterations_per_s"]
            without = per_iteration if prior == "none" else without
            share = f"{1.0 - without / per_iteration:.2f}" if without is not None and prior != "none" else "-"
            print(f"| {size} | {prior} | {report['iterations']} | {count} | {report['iterations_per_s']:.2f} | "
                  f"{per_iteration * 1e3:.0f} | {render_s * 1e3:.0f} | {per_iteration / render_s:.2f} | {share} |",
                  flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quality", action="store_true", help="the held-out quality table (long: full size)")
    parser.add_argument("--scenarios", default=",".join(QUALITY_SCENARIOS))
    parser.add_argument("--fit", default="keypoints3d", choices=("keypoints3d", "keypoints2d", "provided"),
                        help="how stage 02 gets the bodies (provided = the ground truth)")
    parser.add_argument("--seed", type=int, default=SEED, help="the fixture scenes' seed")
    parser.add_argument("--no-speed", action="store_true", help="skip the speed runs")
    parser.add_argument("--priors", default="none,surface",
                        help="stage 06's priors to compare, in order; KIND@KEY=VALUE[@KEY=VALUE] runs a prior with "
                             "parameter overrides (surface@prior_surface.garments=false)")
    parser.add_argument("--placement-from-truth", action="store_true",
                        help="move each fitted person onto the truth by one similarity before stage 03 (a diagnostic)")
    parser.add_argument("--exact-keypoints", action="store_true",
                        help="replace the fixture's noisy keypoints by exact ones, same frames and confidences "
                             "(a diagnostic: what the keypoints' noise costs)")
    parser.add_argument("--shape-from-truth", action="store_true",
                        help="state every person's true body shape to stage 02 (a diagnostic: what the shape costs)")
    parser.add_argument("--scene-scale", type=float, default=1.0,
                        help="move every fitted person about the camera by this factor before stage 03 (a diagnostic: "
                             "what the one scale a single view cannot tell costs; 1.01 = 1%% farther and larger)")
    parser.add_argument("--pictures", type=Path, default=None, help="save canonical turntables here")
    parser.add_argument("--params", default="", help="parameter overrides of the quality runs, as make's PARAMS")
    parser.add_argument("--bg-schedule", type=float, default=None,
                        help="stage 04's schedule_scale in the quality runs (default: pipeline.yaml's)")
    parser.add_argument("--keep", type=Path, default=None,
                        help="run in this folder and keep it (default: a temporary folder, removed at the end)")
    args = parser.parse_args()
    torch.set_num_threads(THREADS)
    priors = tuple(args.priors.split(","))
    if args.keep is not None:
        args.keep.mkdir(parents=True, exist_ok=True)
    with contextlib.nullcontext(str(args.keep)) if args.keep is not None else tempfile.TemporaryDirectory() as tmp:
        if args.quality:
            print("### stage 06 per prior: held-out quality at full size, bodies fitted to keypoints\n")
            quality(args.scenarios.split(","), Path(tmp), args.fit, args.bg_schedule, args.seed, args.params,
                    priors, args.pictures,
                    Diagnostics(args.placement_from_truth, args.exact_keypoints, args.shape_from_truth,
                                args.scene_scale))
        if not args.no_speed:
            print(f"\n### stage 06 speed on demo ({THREADS} threads, schedule_scale {SPEED_SCHEDULE})\n")
            speed(Path(tmp) / "speed", priors)
    return 0


if __name__ == "__main__":
    sys.exit(main())
