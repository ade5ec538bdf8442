"""`make demo`: generate the embedded demo scene (once), run the whole pipeline on it, say where
the results are and print the metrics table of stage 07.

    python -m glimpse.demo [--out runs] [--size small] [--params "section.key=value ..."]
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from pathlib import Path

from glimpse.config import REPO_ROOT
from glimpse.pipeline.stages import STAGES

SCENARIO = "demo"


def main() -> int:
    parser = argparse.ArgumentParser(prog="python -m glimpse.demo", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path("runs"))
    parser.add_argument("--size", default="small", choices=("tiny", "small", "full"))
    parser.add_argument("--params", default="", help="parameter overrides, as make's PARAMS")
    args = parser.parse_args()
    scene = args.out / "scenes" / f"{SCENARIO}_{args.size}"
    if not (scene / "scene.yaml").is_file():
        from glimpse.fixtures.scenes import make_scene

        print(f"demo: generating the synthetic scene {scene} (once)", flush=True)
        make_scene(SCENARIO, scene, args.size, seed=0)
    result = subprocess.run(["make", "--no-print-directory", "-C", str(REPO_ROOT), "all", f"SCENE={scene.resolve()}",
                             f"OUT={args.out.resolve()}", f"PARAMS={args.params}"])
    run_dir = args.out / f"{SCENARIO}_{args.size}"
    done = [s.name for s in STAGES if (run_dir / s.name / "manifest.json").is_file()]
    pending = next((s for s in STAGES if s.name not in done), None)
    print(f"\ndemo: scene {scene}; results in {run_dir}/")
    for name in done:
        print(f"  {name}: {run_dir / name}")
    if result.returncode == 0:
        print("demo: the whole pipeline ran; stage 07's metrics:\n")
        print(_tables(run_dir / "07_eval" / "metrics.md"))
        print(f"demo: the run report (plots, stills, videos, timings): open {(run_dir / 'report.html').resolve()} in a "
              f"browser; `glimpse view {run_dir}` to look around the scene")
        return 0
    print(f"demo: stage {pending.name if pending else '?'} failed (see above)", file=sys.stderr)
    return result.returncode


def _tables(metrics_md: Path) -> str:
    """The tables of metrics.md without their protocol lines (those stay in the file)."""
    kept = [line for line in metrics_md.read_text().splitlines() if not line.startswith(("- ", "Protocol:"))]
    return re.sub(r"\n{3,}", "\n\n", "\n".join(kept)).strip() + f"\n\n(each table's protocol: {metrics_md})"


if __name__ == "__main__":
    sys.exit(main())
