"""The real Makefile with stand-in stages: each stage script records that it ran (and may be made slow),
so that tests of make's behaviour do not depend on what the real stages compute."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml

from glimpse.pipeline.stages import STAGE_NAMES
from glimpse.scene import SceneWriter

REPO = Path(__file__).resolve().parent.parent

STAGE_SCRIPT = """
import json, os, sys, time
sys.path.insert(0, {repo!r})
from glimpse.pipeline.runner import stage_main
STAGE = {stage!r}
def body(ctx):
    with open(os.environ["RAN_LOG"], "a") as f:
        f.write(STAGE + "\\n")
    (ctx.out / "partial.txt").write_text("started")
    if os.environ.get("SLOW_STAGE") == STAGE:
        time.sleep(float(os.environ.get("SLOW_SECONDS", "120")))
    (ctx.out / "params.json").write_text(json.dumps(ctx.params, sort_keys=True))
stage_main(STAGE, body, "test stage")
"""


def write_tiny_scene(root: Path) -> None:
    scene = SceneWriter(root, "tiny", 10, "static")
    rng = np.random.default_rng(0)
    for i in range(3):
        scene.frame(i, rng.integers(0, 255, (12, 16, 3), dtype=np.uint8))
    keypoints = np.concatenate([rng.uniform(0, 12, (3, 17, 2)), np.ones((3, 17, 1))], axis=2)
    scene.keypoints2d("p0", np.arange(3), "coco17", keypoints)  # the pipeline runs only scenes with people
    scene.finish()


def make_setup(tmp_path: Path, scene: Path, out: Path) -> tuple[Path, Path, Path, dict, list[str]]:
    """A tiny scene at ``scene``, recording stage scripts and a pipeline.yaml with a test knob per stage under
    ``tmp_path``; returns (scene, out, ran log, environment, make's arguments before the target)."""
    stages_dir = tmp_path / "stages"
    write_tiny_scene(scene)
    for name in STAGE_NAMES:
        (stages_dir / name).mkdir(parents=True)
        (stages_dir / name / "run.py").write_text(STAGE_SCRIPT.format(repo=str(REPO), stage=name))
    defaults = yaml.safe_load((REPO / "pipeline.yaml").read_text())
    for name in STAGE_NAMES:  # a test-only parameter in every stage's section (the test's own copy)
        defaults.setdefault(name, {})["knob"] = 1
    # The CPU named, so that resolving `schedule_scale: auto` need not import torch to look for CUDA in every
    # process (1.5 s each; these stages compute nothing). Schedules on "auto": tests/test_auto_schedule.py.
    defaults["compute"]["device"] = "cpu"
    pipeline_yaml = tmp_path / "pipeline.yaml"
    pipeline_yaml.write_text(yaml.safe_dump(defaults))
    log = tmp_path / "ran.log"
    log.write_text("")
    env = dict(os.environ, RAN_LOG=str(log))
    args = ["make", "-C", str(REPO), f"SCENE={scene}", f"OUT={out}", f"STAGES_DIR={stages_dir}",
            f"PIPELINE_YAML={pipeline_yaml}", f"PY={sys.executable}"]
    return scene, out, log, env, args


def make(args, env, *extra, target="all"):
    return subprocess.run([*args, target, *extra], env=env, capture_output=True, text=True, timeout=300)


def ran(log: Path, since: int) -> list[str]:
    return log.read_text().split()[since:]


