"""Where the pipeline's time goes: every stage's wall time, and stage 04's and stage 06's iterations phase
by phase (data, posing, render, losses, backward, optimiser, prior, densification, the rest), on the demo.

The demo fixture (--size small: 128x96, 24 frames, what `make demo` runs) goes through the whole pipeline
once with `glimpse run`, default parameters unless --params, in a fresh output folder. Stages 04 and 06
time the phases of their iterations (glimpse.gaussians.phases) and write them in their reports; the stages'
manifests hold their wall times. This prints both as tables: milliseconds per iteration and each phase's
share of the training time. Phases that call the rasterizer: render (projection, binning, compositing
forward) and backward (every gradient, the compositor's among them: bench/raster.py times it alone).

    .venv/bin/python bench/phase_profile.py [--size small|full] [--params "section.key=value ..."] [--work DIR]
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

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from glimpse.pipeline.stages import STAGES  # noqa: E402

SCENARIO, SEED = "demo", 0
TRAINING_STAGES = {"04_bg_pretrain": "stage 04 (background)", "06_joint_opt": "stage 06 (joint)"}


def run_pipeline(scene: Path, out: Path, params: str) -> float:
    """Every stage on ``scene`` into ``out`` (fresh); returns the wall seconds of the whole run."""
    env = {**os.environ, "OMP_WAIT_POLICY": os.environ.get("OMP_WAIT_POLICY", "passive")}
    started = time.perf_counter()
    subprocess.run([sys.executable, "-m", "glimpse", "run", "--scene", str(scene), "--out", str(out),
                    "--params", params], cwd=ROOT, env=env, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - started


def stage_table(run_dir: Path, wall_s: float) -> str:
    rows = ["| stage | seconds | share |", "|---|---:|---:|"]
    totals = {s.name: json.loads((run_dir / s.name / "manifest.json").read_text())["timings_s"]["total"]
              for s in STAGES}
    for name, seconds in totals.items():
        rows.append(f"| {name} | {seconds:.1f} | {100 * seconds / wall_s:.0f}% |")
    rows.append(f"| outside the stages (start-up, validation, make) | {wall_s - sum(totals.values()):.1f} | "
                f"{100 * (wall_s - sum(totals.values())) / wall_s:.0f}% |")
    rows.append(f"| **whole run** | **{wall_s:.1f}** | |")
    return "\n".join(rows)


def phase_table(report: dict) -> str:
    phases, iterations = report["phase_seconds"], report["iterations"] - report["resumed_from_iteration"]
    total = sum(phases.values())
    rows = [f"{iterations} iterations, {1000 * report['training_s'] / iterations:.1f} ms each "
            f"({report['iterations_per_s']:.1f} per second)\n", "| phase | ms per iteration | share |", "|---|---:|---:|"]
    for name, seconds in phases.items():
        rows.append(f"| {name} | {1000 * seconds / iterations:.2f} | {100 * seconds / total:.1f}% |")
    return "\n".join(rows)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--size", default="small", choices=("tiny", "small", "full"))
    parser.add_argument("--params", default="", help="parameter overrides, as make's PARAMS")
    parser.add_argument("--work", type=Path, help="folder for the scene and the run (default: a temporary one)")
    args = parser.parse_args()
    from glimpse.fixtures.scenes import make_scene

    with tempfile.TemporaryDirectory(prefix="glimpse-profile-") as temporary:
        work = args.work or Path(temporary)
        scene, out = work / "scene", work / f"out-{int(time.time())}"
        if not (scene / "scene.yaml").is_file():
            make_scene(SCENARIO, scene, args.size, seed=SEED)
        wall_s = run_pipeline(scene, out, args.params)
        run_dir = next(folder for folder in out.iterdir() if (folder / STAGES[0].name).is_dir())  # OUT/<scene name>
        print(f"demo scene ({args.size}), default parameters{' + ' + args.params if args.params else ''}, "
              f"{os.cpu_count()} CPUs\n")
        print(stage_table(run_dir, wall_s))
        for stage, title in TRAINING_STAGES.items():
            print(f"\n{title}: ", end="")
            print(phase_table(json.loads((run_dir / stage / "report.json").read_text())))
    return 0


if __name__ == "__main__":
    sys.exit(main())
