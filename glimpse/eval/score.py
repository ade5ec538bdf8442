"""Stage 07's metrics: render each scored view from stage 06's result and compare.

Three tables (GTU's protocol first, MU ``Evaluator`` / RW ``render_set`` in the official code):
- **humans**: the people alone (every person of that frame, refined poses) rendered on black,
  against the ground truth blacked out outside the union of the people's masks; whole-frame
  PSNR / SSIM / LPIPS.
- **per person**: the same people-only render against the raw ground truth, restricted to that
  person's mask (masked PSNR, SSIM map mean inside the mask, LPIPS with both images zeroed
  outside it), where per-person ground-truth masks exist.
- **composite**: background and people together against the whole ground-truth frame.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import torch

from glimpse.background.stage import render_camera
from glimpse.eval.views import ScoredView, ViewSet
from glimpse.gaussians.model import GaussianModel
from glimpse.humans.person import PersonGaussians
from glimpse.joint.compose import frame_gaussians, render_frame
from glimpse.lpips import LPIPS
from glimpse.metrics_table import (
    EvalProtocol, FrameMetrics, MetricsRow, frame_metrics, summarize, table_json, table_markdown,
)
from glimpse.render.config import RenderConfig

METRICS_FORMAT = "glimpse-eval-metrics/1"
BLACK = (0.0, 0.0, 0.0)


@dataclass
class EvalTables:
    """Rows and protocol of each table, keyed "humans", "people", "composite"."""

    rows: dict[str, list[MetricsRow]]
    protocols: dict[str, EvalProtocol]


@torch.no_grad()
def render_view(view: ScoredView, people: list[PersonGaussians], background: GaussianModel | None,
                render: RenderConfig, device: torch.device) -> torch.Tensor:
    """[H, W, 3] in [0, 1]: the people of the view's frame (and the background when given), on black."""
    camera = render_camera(view.camera, view.width, view.height, device)
    gaussians = frame_gaussians(camera, view.frame_id, people, render.sh_degree, background, render.sh_degree)
    if len(gaussians.means) == 0:
        return torch.zeros(view.height, view.width, 3, device=device)
    return render_frame(camera, gaussians, len(people), render).rgb.clamp(0.0, 1.0)


def score_views(view_set: ViewSet, people: list[PersonGaussians], background: GaussianModel, render: RenderConfig,
                lpips_module: LPIPS, device: torch.device) -> EvalTables:
    humans: list[FrameMetrics] = []
    composite: list[FrameMetrics] = []
    per_person: dict[str, list[FrameMetrics]] = {p.pid: [] for p in people}
    for view in view_set.views:
        image, union, masks = view.read()
        target = torch.as_tensor(image, device=device).float() / 255.0
        union_t = torch.as_tensor(union, device=device)
        people_only = render_view(view, people, None, render, device)
        humans.append(frame_metrics(view.name, people_only, target * union_t[..., None], lpips_module))
        for pid, mask in masks.items():
            if pid in per_person and mask.any():
                per_person[pid].append(frame_metrics(view.name, people_only, target, lpips_module,
                                                     torch.as_tensor(mask, device=device)))
        full = render_view(view, people, background, render, device)
        composite.append(frame_metrics(view.name, full, target, lpips_module))
    net = lpips_module.net_name
    where = view_set.description
    protocols = {
        "humans": EvalProtocol("ground truth blacked out outside the union of the people's masks; the render shows "
                               "the people only", BLACK, where, net),
        "people": EvalProtocol("each person's own ground-truth mask (frames where it is not empty); the render "
                               "shows every person of the frame, so people in front are accounted for", None, where,
                               net),
        "composite": EvalProtocol("none: background and people against the whole frame", None, where, net),
    }
    rows = {"humans": [summarize("humans only", humans)],
            "people": [summarize(pid, frames) for pid, frames in per_person.items() if frames],
            "composite": [summarize("background + humans", composite)]}
    return EvalTables(rows, protocols)


TITLES = {"humans": "Humans only (GTU protocol)", "people": "Per person", "composite": "Full composite"}


def write_tables(tables: EvalTables, prior: str, source: str, out: Path) -> dict:
    """metrics.json (every table with its per-frame values) and metrics.md; returns the JSON document."""
    doc = {"format": METRICS_FORMAT, "prior": prior, "views": source,
           "tables": {name: table_json(rows, tables.protocols[name]) for name, rows in tables.rows.items() if rows}}
    (out / "metrics.json").write_text(json.dumps(doc, indent=1) + "\n")
    header = f"Prior: {prior}. Views: {source}.\n\n"
    parts = [table_markdown(rows, tables.protocols[name], TITLES[name]) for name, rows in tables.rows.items() if rows]
    (out / "metrics.md").write_text(header + "\n".join(parts))
    return doc


def headline(tables: EvalTables) -> dict[str, float]:
    """The humans-only and composite means, for the manifest and the demo's printout."""
    h, c = tables.rows["humans"][0], tables.rows["composite"][0]
    return {"humans_psnr_db": round(h.psnr, 3), "humans_ssim": round(h.ssim, 4), "humans_lpips_x100": round(h.lpips, 3),
            "composite_psnr_db": round(c.psnr, 3)}
