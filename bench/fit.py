"""Stage 02 fitting accuracy and time on fixture scenes with known bodies (glimpse.fit).

For each scenario and person, the body is fitted from the scene's keypoints (coco17) under
three conditions, then compared with the true body (glimpse.fit.evaluate, 24 joints):
  clean:     exact keypoints (the fixture's confidences: occluded or 10% dropped ones unused)
  noisy:     the fixture's keypoints (3D: 1.5 cm noise; 2D: 1.5 px at 320 px wide), 10% dropped
  noisy-30%: the same with further keypoints dropped at random, 30% dropped in all
Prints one Markdown table per size: mean per-joint error as fitted and after alignment, and
fitting seconds (2 threads). `--full` adds the full-size (320x240, 100 frames) scenes.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from glimpse.body.keypoints import keypoint_map  # noqa: E402
from glimpse.body.model import BodyModel  # noqa: E402
from glimpse.config import config_from_mapping, load_pipeline_yaml  # noqa: E402
from glimpse.fit.config import FitConfig  # noqa: E402
from glimpse.fit.evaluate import joint_errors  # noqa: E402
from glimpse.fit.stage import Fitter  # noqa: E402
from glimpse.fixtures.scenes import FREE_BODY, KEYPOINT_DROP_RATE, make_scene  # noqa: E402
from glimpse.io.cameras_json import read_cameras_json  # noqa: E402
from glimpse.scene import load_scene  # noqa: E402

THREADS = 2
SEED = 0
SCENARIOS = ("demo", "lower_body_occluded", "moving_camera", "crowd")
TOTAL_DROP = 0.3
CONDITIONS = ("clean", "noisy", "noisy-30%")


def _degrade(scene: Path, truth: Path, model: BodyModel, condition: str, rng: np.random.Generator) -> None:
    """Rewrite every person's keypoint files in ``scene`` for ``condition``."""
    _, _, cameras = read_cameras_json(scene / "cameras.json")
    extra_drop = (TOTAL_DROP - KEYPOINT_DROP_RATE) / (1 - KEYPOINT_DROP_RATE)
    for person in sorted((scene / "humans").iterdir()):
        true = np.load(truth / f"{person.name}_body.npz")
        for name, key in (("keypoints3d.npz", "joints"), ("keypoints2d.npz", "keypoints")):
            data = dict(np.load(person / name))
            values = data[key]
            if condition == "clean":
                rows = data["frame_ids"]
                with torch.no_grad():
                    out = model(torch.as_tensor(true["betas"])[None], torch.as_tensor(true["global_orient"][rows]),
                                torch.as_tensor(true["body_pose"][rows]), torch.as_tensor(true["transl"][rows]))
                exact = keypoint_map(str(data["layout"]), model.data)(out.joints, out.vertices).numpy()
                if key == "keypoints":
                    exact = np.stack([cameras[int(fid)].project(points)[0] for fid, points in zip(rows, exact)])
                seen = values[..., -1:] > 0
                values[..., :-1] = np.where(seen, exact, 0.0)
            elif condition == "noisy-30%":
                values[..., -1] = np.where(rng.random(values.shape[:2]) < extra_drop, 0.0, values[..., -1])
            np.savez(person / name, **data)


def evaluate(size: str, root: Path) -> list[dict]:
    raw = load_pipeline_yaml()["02_smpl_fit"]
    config = config_from_mapping(FitConfig, {**raw, "overlay": False}, "pipeline.yaml 02_smpl_fit")
    model = BodyModel.from_file(FREE_BODY, dtype=torch.float64)
    rows = []
    for scenario in SCENARIOS:
        original = make_scene(scenario, root / f"{scenario}_{size}", size, seed=SEED)
        truth = original.with_name(original.name + ".groundtruth")
        for condition in CONDITIONS:
            scene_dir = root / f"{scenario}_{size}_{condition}"
            shutil.rmtree(scene_dir, ignore_errors=True)
            shutil.copytree(original, scene_dir)
            _degrade(scene_dir, truth, model, condition, np.random.default_rng(SEED))
            scene = load_scene(scene_dir)
            _, _, cameras = read_cameras_json(scene_dir / "cameras.json")
            for mode in ("keypoints3d", "keypoints2d"):
                fitter = Fitter(scene, model, cameras, FitConfig(**{**vars(config), "mode": mode}), "metres")
                for pid, person in sorted(scene.humans.items()):
                    started = time.perf_counter()
                    fit = fitter.fit_person(person)
                    seconds = time.perf_counter() - started
                    errors = joint_errors(model, fit.params, dict(np.load(truth / f"{pid}_body.npz")))
                    rows.append({"scenario": scenario, "person": pid, "mode": mode, "condition": condition,
                                 "seconds": seconds, **errors})
    return rows


def print_table(size: str, rows: list[dict]) -> None:
    print(f"\n### {size} fixtures: mean per-joint error, cm (24 joints, fitted frames)\n")
    print("| mode | condition | people | as fitted | sequence-aligned | frame-aligned (PA) | worst person, seq.-aligned | s per person |")
    print("|---|---|---|---|---|---|---|---|")
    for mode in ("keypoints3d", "keypoints2d"):
        for condition in CONDITIONS:
            sel = [r for r in rows if r["mode"] == mode and r["condition"] == condition]
            worst = max(sel, key=lambda r: r["sequence_aligned_m"])
            print(f"| {mode} | {condition} | {len(sel)} | {100 * np.mean([r['mpjpe_m'] for r in sel]):.2f} | "
                  f"{100 * np.mean([r['sequence_aligned_m'] for r in sel]):.2f} | "
                  f"{100 * np.mean([r['frame_aligned_m'] for r in sel]):.2f} | "
                  f"{100 * worst['sequence_aligned_m']:.2f} ({worst['scenario']} {worst['person']}) | "
                  f"{np.mean([r['seconds'] for r in sel]):.1f} |")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--full", action="store_true", help="also the full-size scenes (minutes)")
    parser.add_argument("--only-full", action="store_true", help="the full-size scenes only")
    parser.add_argument("--per-person", action="store_true", help="print every person's row too")
    args = parser.parse_args()
    torch.set_num_threads(THREADS)
    cache = Path(os.environ.get("GLIMPSE_CACHE", Path.home() / ".cache" / "glimpse")) / "bench_fit"
    cache.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=cache) as tmp:
        for size in ("full",) if args.only_full else ("small", "full") if args.full else ("small",):
            rows = evaluate(size, Path(tmp))
            print_table(size, rows)
            if args.per_person:
                for r in rows:
                    print(f"{r['scenario']} {r['person']} {r['mode']} {r['condition']}: "
                          f"{100 * r['mpjpe_m']:.1f} / {100 * r['sequence_aligned_m']:.1f} / "
                          f"{100 * r['frame_aligned_m']:.1f} cm, {r['seconds']:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
