"""A batch's summary: ``OUT/batch.json`` (glimpse-batch/1) and ``OUT/batch.md``: per scene its status,
attempts, the stages each attempt ran, time and stage 07's numbers side by side, then the mean and spread of
each number over the scenes that have it (the form of the paper's tables)."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from glimpse.batch.jobs import HEADLINE_KEYS, STATUSES, SceneResult
from glimpse.io.staging import staged_file

BATCH_FORMAT = "glimpse-batch/1"
COLUMNS = {"humans_psnr_db": ("humans PSNR", 2), "humans_ssim": ("humans SSIM", 4),
           "humans_lpips_x100": ("humans LPIPS×100", 2), "seen_psnr_db": ("seen PSNR", 2),
           "seen_lpips_x100": ("seen LPIPS×100", 2), "never_seen_psnr_db": ("never-seen PSNR", 2),
           "never_seen_lpips_x100": ("never-seen LPIPS×100", 2), "composite_psnr_db": ("full-frame PSNR", 2)}


def aggregate(results: list[SceneResult]) -> dict[str, dict[str, float]]:
    """Per headline number: mean, standard deviation (population) and count over the scenes that have it."""
    out = {}
    for key in HEADLINE_KEYS:
        values = [r.headline[key] for r in results if key in r.headline]
        if values:
            out[key] = {"mean": float(np.mean(values)), "std": float(np.std(values)), "scenes": len(values)}
    return out


def summary_doc(results: list[SceneResult], executor: str) -> dict:
    return {"format": BATCH_FORMAT, "executor": executor,
            "counts": {status: sum(r.status == status for r in results) for status in STATUSES},
            "scenes": [asdict(r) for r in results], "aggregate": aggregate(results)}


def summary_markdown(doc: dict) -> str:
    keys = [key for key in HEADLINE_KEYS if any(key in s["headline"] for s in doc["scenes"])]
    counts = ", ".join(f"{n} {status}" for status, n in doc["counts"].items() if n)
    lines = [f"# Batch ({doc['executor']} executor): {counts}", "",
             "| scene | status | attempts | stages run (per attempt) | seconds | "
             + " | ".join(COLUMNS[k][0] for k in keys) + " |",
             "|---|---|---:|---|---:|" + "---:|" * len(keys)]
    for scene in doc["scenes"]:
        ran = "; ".join(",".join(s.split("_")[0] for s in a["stages_run"]) or "none" for a in scene["attempts"])
        numbers = [f"{scene['headline'][k]:.{COLUMNS[k][1]}f}" if k in scene["headline"] else "–" for k in keys]
        lines.append(f"| {scene['label']} | {scene['status']} | {len(scene['attempts'])} | {ran} | "
                     f"{scene['seconds']:.0f} | " + " | ".join(numbers) + " |")
    if doc["aggregate"]:
        cells = [f"{doc['aggregate'][k]['mean']:.{COLUMNS[k][1]}f} ± {doc['aggregate'][k]['std']:.{COLUMNS[k][1]}f}"
                 if k in doc["aggregate"] else "–" for k in keys]
        lines.append("| **mean ± std** | | | | | " + " | ".join(cells) + " |")
    lines += ["", "Numbers: stage 07's held-out metrics of each run (metrics.md in each run folder gives the "
                  "protocol); mean ± population standard deviation over the scenes that finished."]
    failed = [s for s in doc["scenes"] if s["status"] != "done"]
    for scene in failed:
        lines += ["", f"## {scene['label']}: {scene['status']}", "", "```", scene["error"] or "(no output)", "```",
                  f"Logs: {', '.join(a['log'] for a in scene['attempts'])}"]
    return "\n".join(lines) + "\n"


def write_summary(results: list[SceneResult], executor: str, out: Path) -> tuple[Path, Path]:
    """OUT/batch.json and OUT/batch.md; their paths."""
    doc = summary_doc(results, executor)
    json_path, md_path = out / "batch.json", out / "batch.md"
    for path, text in ((json_path, json.dumps(doc, indent=1) + "\n"), (md_path, summary_markdown(doc))):
        with staged_file(path) as tmp:
            tmp.write_text(text)
    return json_path, md_path
