"""``glimpse run``: lock a run folder, prepare it, and let make run the stages that are out of date.

make is the orchestrator (mk/pipeline.mk, run from inside ``OUT/<scene>/`` so that its targets are
relative paths); this module is what stands around it: the run's lock, taken before anything in the
run folder is written and handed down to every stage make starts, and the user's paths, which reach
make's recipes only as environment variables (quoted there), never as text a shell would read.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

from glimpse.errors import GlimpseError
from glimpse.pipeline.prepare import locate_run, prepare_run, run_lock
from glimpse.pipeline.stages import named_stage

REPO_ROOT = Path(__file__).resolve().parent.parent.parent
PIPELINE_MAKEFILE = REPO_ROOT / "mk" / "pipeline.mk"
# Environment variables the stage recipes of mk/pipeline.mk read.
STAGE_ENV = ("GLIMPSE_PYTHON", "GLIMPSE_STAGES_DIR", "GLIMPSE_SCENE", "GLIMPSE_OUT")


def run_stages(scene: Path, out: Path, cli_params: str, stage: str | None, python: str,
               stages_dir: Path | None = None, wait_s: float | None = None) -> int:
    """Run every stage that is out of date (``stage`` None: the whole pipeline), or rerun ``stage`` and
    whatever it needs. Returns make's exit status; bad input raises GlimpseError before anything runs."""
    if stage is not None:
        named_stage(stage)
    make = shutil.which("make")
    if make is None:
        raise GlimpseError("the pipeline needs GNU make on PATH (Debian: apt-get install make)")
    run = locate_run(scene, out, stage is None, cli_params)
    with run_lock(run, "make all" if stage is None else f"make {stage}", wait_s) as lock_fd:
        prepare_run(scene, out, cli_params, whole_pipeline=stage is None)
        env = dict(os.environ, GLIMPSE_PARAMS=cli_params, GLIMPSE_PYTHON=python,
                   GLIMPSE_STAGES_DIR=str((stages_dir or REPO_ROOT / "stages").absolute()),
                   GLIMPSE_SCENE=str(Path(scene).absolute()), GLIMPSE_OUT=str(Path(out).absolute()))
        if env.get("GLIMPSE_PIPELINE_YAML"):  # the stages run in the run folder: relative paths would move
            env["GLIMPSE_PIPELINE_YAML"] = str(Path(env["GLIMPSE_PIPELINE_YAML"]).absolute())
        targets = ["all"] if stage is None else ["-W", f".params/{stage}.json", f"{stage}/manifest.json"]
        command = [make, "--no-print-directory", "-C", str(run.root), "-f", str(PIPELINE_MAKEFILE), *targets]
        return subprocess.run(command, env=env, pass_fds=(lock_fd,)).returncode
