"""Peak memory of stages 04 and 06 against the number of input frames: flat with the frame cache.

The demo fixture (--size: small, 128x96 and 24 frames, by default; medium is 480x360 and 30
frames) goes through stages 01-04 once; its outputs are then repeated (ping-pong over its frames:
frames, cameras, bodies, masks) into runs of 100, 500 and 2,000 frames, and each stage's own code (train_background, train_joint: training on a short
schedule, then rendering and scoring every input view) runs on them in a fresh process whose peak
resident memory is read from the kernel (wait4). Each stage runs twice per length: with the default
`compute.frame_cache` and, as the baseline measured in the same run, with a cache as large as the
video (every frame held, as before the cache). The stages run on the CPU here; on a GPU the frames
held live in GPU memory instead, the same count.

    .venv/bin/python bench/memory.py [--size small|medium] [--frames 100 500 2000] [--stages 04 06]
                                     [--baseline-up-to FRAMES]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from glimpse.body.params import BodyParams, read_body_params, write_body_params  # noqa: E402
from glimpse.fixtures.scenes import make_scene  # noqa: E402
from glimpse.io.cameras_json import read_cameras_json, write_cameras_json  # noqa: E402
from glimpse.io.images import frame_files, frame_name  # noqa: E402
from tests.stage_helpers import run  # noqa: E402

SEED = 0
UPSTREAM = ("01_sfm", "02_smpl_fit", "03_masks", "04_bg_pretrain")
# Short schedules: memory does not depend on the iteration count, and every view is still rendered once.
PARAMS = ("04_bg_pretrain.schedule_scale=0.003 04_bg_pretrain.render_video=false "
          "06_joint_opt.schedule_scale=0.001 06_joint_opt.render_video=false")


def ping_pong(count: int, source: int) -> list[int]:
    """Source frame index for each of ``count`` frames: 0 .. source-1 .. 0 .. (a person walks back and forth)."""
    period = 2 * (source - 1)
    return [k % period if k % period < source else period - k % period for k in range(count)]


def _link_frames(source: dict[int, Path], target: Path, order: list[int], ids: list[int]) -> None:
    """Frame k of the long run is source frame ``ids[order[k]]``, where ``source`` has it (hard links)."""
    target.mkdir(parents=True, exist_ok=True)
    for new, old in enumerate(order):
        if ids[old] in source:
            os.link(source[ids[old]], target / f"{frame_name(new)}{source[ids[old]].suffix}")


def repeat_run(run_dir: Path, count: int, target: Path) -> None:
    """Stage 01-04 outputs of ``run_dir`` repeated to ``count`` frames under ``target``."""
    width, height, cameras = read_cameras_json(run_dir / "01_sfm" / "cameras.json")
    ids = sorted(cameras)
    order = ping_pong(count, len(ids))
    (target / "01_sfm").mkdir(parents=True, exist_ok=True)
    write_cameras_json(target / "01_sfm" / "cameras.json", width, height,
                       {new: cameras[ids[old]] for new, old in enumerate(order)})
    masks = run_dir / "03_masks"
    for folder in [run_dir / "01_sfm" / "frames", *sorted(p for p in (masks / "masks").iterdir() if p.is_dir()),
                   *sorted(p for p in (masks / "occluders").glob("*") if p.is_dir())]:
        _link_frames(frame_files(folder), target / folder.relative_to(run_dir), order, ids)
    for body_file in sorted((run_dir / "02_smpl_fit" / "humans").glob("*/body.npz")):
        body = read_body_params(body_file)
        row_of = {int(f): r for r, f in enumerate(body.frame_ids)}
        new_ids = np.array([new for new, old in enumerate(order) if ids[old] in row_of], dtype=np.int64)
        rows = np.array([row_of[ids[old]] for old in order if ids[old] in row_of], dtype=np.int64)
        out = target / "02_smpl_fit" / "humans" / body_file.parent.name / "body.npz"
        out.parent.mkdir(parents=True, exist_ok=True)
        write_body_params(out, BodyParams(new_ids, body.betas, body.global_orient[rows], body.body_pose[rows],
                                          body.transl[rows], body.scale, body.body_model, body.interpolated[rows]))
    (target / "04_bg_pretrain").mkdir(parents=True, exist_ok=True)
    os.link(run_dir / "04_bg_pretrain" / "background.ply", target / "04_bg_pretrain" / "background.ply")


def child(stage: str, run_dir: Path, cache: int, out: Path) -> None:
    """One stage's own code on ``run_dir``'s inputs (in this process: the parent reads its peak memory)."""
    from glimpse.body.models import BodyModels
    from glimpse.compute import ComputeConfig, apply_compute
    from glimpse.config import config_from_mapping, load_pipeline_yaml, parse_cli_params, resolve_params
    from glimpse.io.frame_cache import FrameCacheSize
    from glimpse.pipeline.sections import SECTION_CONFIGS

    params = resolve_params(load_pipeline_yaml(), {}, parse_cli_params(PARAMS), "bench/memory.py")
    section = {name: config_from_mapping(SECTION_CONFIGS[name], params[name], name) for name in
               ("04_bg_pretrain", "06_joint_opt", "render", "body", "compute")}
    compute: ComputeConfig = section["compute"]
    apply_compute(compute)
    frames = FrameCacheSize(cache, min(compute.frame_read_ahead, cache - 1), compute.lpips_target_cache_mb)
    width, height, cameras = read_cameras_json(run_dir / "01_sfm" / "cameras.json")
    bodies = {p.parent.name: read_body_params(p) for p in sorted((run_dir / "02_smpl_fit" / "humans").glob("*/body.npz"))}
    import torch

    device = torch.device("cpu")
    if stage == "04":
        from glimpse.background.stage import BackgroundInputs, train_background

        inputs = BackgroundInputs(cameras, width, height, run_dir / "01_sfm" / "frames",
                                  run_dir / "03_masks" / "masks" / "union", None, bodies, 25.0)
        train_background(inputs, section["04_bg_pretrain"], section["render"], SEED, device, frames, out / "work",
                         "bench", out)
    else:
        from glimpse.gaussians.model import GaussianModel
        from glimpse.gaussians.ply import read_gaussians_ply
        from glimpse.joint.stage import JointInputs, train_joint
        from glimpse.prior.config import SurfacePriorConfig

        background = GaussianModel.from_splats(read_gaussians_ply(run_dir / "04_bg_pretrain" / "background.ply")[0])
        inputs = JointInputs(cameras, width, height, run_dir / "01_sfm" / "frames", run_dir / "03_masks" / "masks",
                             run_dir / "03_masks" / "occluders", bodies, background, 25.0)
        body_models = BodyModels.load(section["body"])
        surface = config_from_mapping(SurfacePriorConfig, params["prior_surface"], "prior_surface")
        train_joint(inputs, section["06_joint_opt"], section["render"], section["body"], body_models, "surface",
                    surface, SEED, device, frames, out / "work", "bench", out)


def measure(stage: str, run_dir: Path, cache: int, out: Path) -> tuple[float, float]:
    """(peak resident memory in MB, seconds) of one child process."""
    started = time.perf_counter()
    process = subprocess.Popen([sys.executable, __file__, "--child", stage, str(run_dir), str(cache), str(out)],
                               stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(process.pid, 0)
    if status != 0:
        raise SystemExit(f"stage {stage} on {run_dir} (cache {cache}) failed")
    return usage.ru_maxrss / 1024.0, time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, nargs="+", default=[100, 500, 2000])
    parser.add_argument("--stages", nargs="+", default=["04", "06"], choices=["04", "06"])
    parser.add_argument("--size", default="small", choices=["small", "medium"])
    parser.add_argument("--baseline-up-to", type=int, default=None,
                        help="measure the every-frame-held baseline only up to this many frames (it is slow)")
    parser.add_argument("--child", nargs=4, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        stage, run_dir, cache, out = args.child
        child(stage, Path(run_dir), int(cache), Path(out))
        return
    from glimpse.config import load_pipeline_yaml

    default_cache = int(load_pipeline_yaml()["compute"]["frame_cache"])
    with tempfile.TemporaryDirectory(prefix="glimpse-bench-memory-") as tmp:
        root = Path(tmp)
        scene = make_scene("demo", root / "scene", args.size, seed=SEED)
        for stage in UPSTREAM:
            run(stage, scene, root / "out", PARAMS)
        source = root / "out" / f"demo_{args.size}"
        width, height, _ = read_cameras_json(source / "01_sfm" / "cameras.json")
        rows = []
        for count in args.frames:
            long_run = root / f"run_{count}"
            repeat_run(source, count, long_run)
            for stage in args.stages:
                variants = [(f"frame_cache {default_cache}", default_cache)]
                if args.baseline_up_to is None or count <= args.baseline_up_to:
                    variants.insert(0, ("every frame held", count))
                for label, cache in variants:
                    peak, seconds = measure(stage, long_run, cache, root / f"out_{stage}_{count}_{cache}")
                    rows.append((stage, count, label, peak, seconds))
                    print(json.dumps({"stage": stage, "frames": count, "cache": label, "peak_mb": round(peak),
                                      "seconds": round(seconds, 1)}), file=sys.stderr, flush=True)
    print(f"| stage | frames ({width}x{height}) | frames held | peak memory, MB | vs {args.frames[0]} frames | s |")
    print("|---|---|---|---|---|---|")
    first = {(stage, label): peak for stage, count, label, peak, _ in rows if count == args.frames[0]}
    for stage, count, label, peak, seconds in rows:
        print(f"| {stage} | {count} | {label} | {peak:.0f} | {peak / first[(stage, label)]:.2f}x | {seconds:.0f} |")


if __name__ == "__main__":
    main()
