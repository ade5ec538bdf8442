"""Run a stage in-process, as make would (same runner, same outputs)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path
from types import ModuleType

from glimpse.pipeline.runner import run_stage

REPO = Path(__file__).resolve().parent.parent


def stage_module(stage: str) -> ModuleType:
    path = REPO / "stages" / stage / "run.py"
    spec = importlib.util.spec_from_file_location(f"stage_{stage}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def run(stage: str, scene: Path, out: Path, params: str = "") -> Path:
    """Run ``stage`` on ``scene`` (and what it writes after publishing, as stage 07's report); returns its
    output folder."""
    module = stage_module(stage)
    return run_stage(stage, scene, out, params, module.run, getattr(module, "write_run_report", None))


def read_json(path: Path) -> dict:
    return json.loads(Path(path).read_text())
