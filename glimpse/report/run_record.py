"""What the report reads from a run folder (``OUT/<scene>/``): each stage's manifest and report, whichever
stages have run. Pure reading; a stage that has not run is simply absent."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from glimpse.config import STAGE_NAMES
from glimpse.errors import GlimpseError

LOG_FILE = "log.txt"


@dataclass(frozen=True)
class RunRecord:
    """A run folder and the JSON its stages wrote.

    manifests: stage -> its manifest.json (only stages that finished).
    reports:   stage -> its report-like JSON (01 report.json, 03 masks.json, 04/06 report.json, 07 metrics.json).
    failed_logs: stage -> the log of its last failed attempt (OUT/<scene>/<stage>.failed.log.txt).
    """

    root: Path
    manifests: dict[str, dict]
    reports: dict[str, dict]
    failed_logs: dict[str, Path]

    @property
    def name(self) -> str:
        return self.root.name

    def stage_dir(self, stage: str) -> Path:
        return self.root / stage

    def has(self, stage: str) -> bool:
        return stage in self.manifests

    def summary(self, stage: str) -> dict[str, Any]:
        return self.manifests.get(stage, {}).get("summary", {})


REPORT_FILES = {"01_sfm": "01_sfm/report.json", "03_masks": "03_masks/masks.json",
                "04_bg_pretrain": "04_bg_pretrain/report.json", "06_joint_opt": "06_joint_opt/report.json",
                "07_eval": "07_eval/metrics.json"}


def _read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise GlimpseError(f"{path}: cannot read it as JSON ({exc}); rerun the stage that writes it") from None


def read_run(root: Path) -> RunRecord:
    """The manifests and reports of every finished stage of the run folder ``root``. Raises GlimpseError when
    ``root`` is not a run folder (no stage has finished there)."""
    root = Path(root)
    manifests = {s: _read_json(root / s / "manifest.json") for s in STAGE_NAMES
                 if (root / s / "manifest.json").is_file()}
    if not manifests:
        raise GlimpseError(f"{root}: not a run folder (no stage's manifest.json in it); a run folder is "
                           "OUT/<scene name>, e.g. runs/demo_small")
    reports = {key: _read_json(root / rel) for key, rel in REPORT_FILES.items()
               if rel.split("/")[0] in manifests and (root / rel).is_file()}
    failed = {s: root / f"{s}.failed.{LOG_FILE}" for s in STAGE_NAMES if (root / f"{s}.failed.{LOG_FILE}").is_file()}
    return RunRecord(root, manifests, reports, failed)


def flatten(mapping: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """{"a": {"b": 1}} -> {"a.b": 1}; lists and scalars are leaves."""
    flat: dict[str, Any] = {}
    for key, value in mapping.items():
        dotted = f"{prefix}{key}"
        if isinstance(value, dict) and value:
            flat.update(flatten(value, dotted + "."))
        else:
            flat[dotted] = value
    return flat


def changed_params(recorded: dict[str, Any], defaults: dict[str, Any]) -> list[tuple[str, Any, Any]]:
    """(dotted key, value the stage ran with, default) for every recorded parameter that differs from the
    default (a key the defaults lack has default None), sorted by key."""
    ran, default = flatten(recorded), flatten(defaults)
    return [(key, value, default.get(key)) for key, value in sorted(ran.items()) if default.get(key) != value]


def warnings_in_log(path: Path, limit: int) -> list[str]:
    """The first ``limit`` WARNING and ERROR lines of a stage's log.txt (without their time stamps)."""
    if not path.is_file():
        return []
    lines = []
    for line in path.read_text(errors="replace").splitlines():
        for level in (" WARNING ", " ERROR "):
            if level in line:
                lines.append(level.strip() + " " + line.split(level, 1)[1])
                break
        if len(lines) >= limit:
            break
    return lines
