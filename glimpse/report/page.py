"""Writing ``OUT/<scene>/report.html`` and its pictures (``OUT/<scene>/report_files/``): the page is built in
full before it replaces the previous one, so a reader never sees half a report."""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

from glimpse.io.staging import staged_file, staged_folder
from glimpse.report import sections
from glimpse.report.config import ReportConfig
from glimpse.report.html import STYLE, esc, section
from glimpse.report.run_record import read_run

REPORT_FILE, ASSETS_FOLDER = "report.html", "report_files"
log = logging.getLogger(__name__)


def write_report(run_root: Path, config: ReportConfig, defaults: dict[str, Any]) -> Path:
    """Write the report of the run folder ``run_root`` (whatever stages have finished there); ``defaults`` are
    pipeline.yaml's sections, against which each stage's parameters are compared. Returns the page's path.
    Raises GlimpseError when ``run_root`` is not a run folder."""
    record = read_run(run_root)
    started = time.perf_counter()
    with staged_folder(record.root / ASSETS_FOLDER) as folder:
        assets = sections.Assets(folder, ASSETS_FOLDER, config)
        parts = [
            ("scene", "Scene and people", sections.scene_section(record)),
            ("metrics", "Metrics", sections.metrics_section(record, assets)),
            ("views", "Held-out and input views: render beside the truth", sections.heldout_section(record, assets)),
            ("training", "Training", sections.training_section(record, assets)),
            ("bodies", "Fitted bodies", sections.bodies_section(record, assets)),
            ("masks", "Masks", sections.masks_section(record, assets)),
            ("videos", "Videos", sections.videos_section(record, config)),
            ("parameters", "Parameters that differ from the defaults", sections.parameters_section(record, defaults)),
            ("timings", "Timings", sections.timings_section(record, assets)),
            ("logs", "Logs", sections.logs_section(record, config)),
        ]
    versions = sorted({m.get("code_version", "?") for m in record.manifests.values()})
    finished = max(m.get("finished_at", "") for m in record.manifests.values())
    nav = "".join(f'<a href="#{anchor}">{esc(title.split(":")[0])}</a>' for anchor, title, _ in parts)
    page = (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>Glimpse run: {esc(record.name)}</title><style>{STYLE}</style></head><body>\n"
            f"<h1>Glimpse run: {esc(record.name)}</h1>\n"
            f'<p class="muted">{esc(record.root.resolve())} · glimpse {esc(", ".join(versions))} · last stage finished '
            f"{esc(finished)} · stages run: {esc(', '.join(record.manifests))}</p>\n"
            f"{sections.headline(record)}\n<nav>{nav}</nav>\n"
            + "\n".join(section(anchor, title, body) for anchor, title, body in parts)
            + "\n</body></html>\n")
    path = record.root / REPORT_FILE
    with staged_file(path) as tmp:
        tmp.write_text(page, encoding="utf-8")
    log.info("report: %s (%.1f s)", path, time.perf_counter() - started)
    return path
