"""Stage 07's metrics: render each scored view from stage 06's result and compare.

The tables (GTU's protocol first, MU ``Evaluator`` / RW ``render_set`` in the official code):
- **humans**: the people alone (every person of that frame, refined poses) rendered on black,
  against the ground truth blacked out outside the union of the people's masks; whole-frame
  PSNR / SSIM / LPIPS.
- **per person**: the same people-only render against the raw ground truth, restricted to that
  person's mask (masked PSNR, SSIM map mean inside the mask, LPIPS with both images zeroed
  outside it), where per-person ground-truth masks exist.
- **seen** and **never seen**: the same people-only render against the same masked ground truth,
  restricted to the pixels whose body surface some input frame saw, and to those no input frame
  saw (glimpse.eval.never_seen): the two split the union mask, so what the reconstruction
  reproduces and what the prior guesses are measured apart; views without such pixels are skipped.
- **composite**: background and people together against the whole ground-truth frame.

The humans, seen and never-seen tables carry two baselines in the same protocol: an empty (black)
render and the fitted bodies drawn flat in each person's mean input colour; the per-person table
carries the flat bodies after each person's row.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from glimpse.cameras.model import render_camera
from glimpse.eval.never_seen import PosedBodies, flat_bodies
from glimpse.eval.views import ScoredView, ViewSet
from glimpse.gaussians.model import GaussianModel
from glimpse.humans.compose import frame_gaussians, render_frame
from glimpse.humans.person import PersonGaussians
from glimpse.io.progress import progress
from glimpse.metrics.lpips import LPIPS
from glimpse.metrics.table import (
    EvalProtocol,
    FrameMetrics,
    MetricsRow,
    frame_metrics,
    frame_metrics_against,
    summarize,
    table_json,
    table_markdown,
)
from glimpse.render.config import RenderConfig

METRICS_FORMAT = "glimpse-eval-metrics/1"
BLACK = (0.0, 0.0, 0.0)


@dataclass
class EvalTables:
    """Rows and protocol of each table, keyed "humans", "people", "seen", "never_seen", "composite"."""

    rows: dict[str, list[MetricsRow]]
    protocols: dict[str, EvalProtocol]


@torch.no_grad()
def render_view(view: ScoredView, people: list[PersonGaussians], background: GaussianModel | None,
                render: RenderConfig, device: torch.device) -> torch.Tensor:
    """[H, W, 3] in [0, 1]: the people of the view's frame (and the background when given), on black."""
    camera = render_camera(view.camera, device)
    gaussians = frame_gaussians(camera, view.frame_id, people, render.sh_degree, background, render.sh_degree)
    if len(gaussians.means) == 0:
        return torch.zeros(view.camera.height, view.camera.width, 3, device=device)
    return render_frame(camera, gaussians, len(people), render).rgb.clamp(0.0, 1.0)


RENDER_ROW, EMPTY_ROW, FLAT_ROW = "humans only", "baseline: empty render (black)", "baseline: bodies in mean colour"


def person_flat_row(pid: str) -> str:
    """The per-person table's label of the flat-bodies baseline in ``pid``'s mask."""
    return f"{pid}, {FLAT_ROW}"


def score_views(view_set: ViewSet, people: list[PersonGaussians], background: GaussianModel, render: RenderConfig,
                lpips_module: LPIPS, device: torch.device, bodies: PosedBodies,
                mean_colours: list[np.ndarray]) -> EvalTables:
    """Score every view of ``view_set``; ``bodies`` and ``mean_colours`` (per person, RGB in [0, 1]) make the
    never-seen masks and the flat-colour baseline."""
    humans: dict[str, list[FrameMetrics]] = {RENDER_ROW: [], EMPTY_ROW: [], FLAT_ROW: []}
    seen: dict[str, list[FrameMetrics]] = {RENDER_ROW: [], EMPTY_ROW: [], FLAT_ROW: []}
    never_seen: dict[str, list[FrameMetrics]] = {RENDER_ROW: [], EMPTY_ROW: [], FLAT_ROW: []}
    composite: list[FrameMetrics] = []
    per_person: dict[str, list[FrameMetrics]] = {}
    for person in people:  # each person's row, then the flat bodies in the same mask
        per_person.update({person.pid: [], person_flat_row(person.pid): []})
    unseen_share: list[float] = []
    for view in progress(view_set.views, desc="07_eval scoring", unit="view"):
        image, union, masks = view.read()
        target = torch.as_tensor(image, device=device).float() / 255.0
        if union is None:  # no ground-truth masks for this view: the full frame only
            full = render_view(view, people, background, render, device)
            composite.append(frame_metrics(view.name, full, target, lpips_module))
            continue
        union_t = torch.as_tensor(union, device=device)
        masked_target = target * union_t[..., None]
        view_bodies = bodies.in_view(view)
        candidates = {RENDER_ROW: render_view(view, people, None, render, device),
                      EMPTY_ROW: torch.zeros_like(target),
                      FLAT_ROW: torch.as_tensor(flat_bodies(view_bodies, mean_colours), device=device)}
        unseen = torch.as_tensor(view_bodies.never_seen & union, device=device)
        seen_px = torch.as_tensor(union & ~view_bodies.never_seen, device=device)
        if union.any():
            unseen_share.append(float(unseen.sum()) / float(union.sum()))
        for table, region in ((humans, None), (seen, seen_px), (never_seen, unseen)):
            if region is None or region.any():
                scores = frame_metrics_against(view.name, list(candidates.values()), masked_target, lpips_module,
                                               region)
                for label, score in zip(candidates, scores, strict=True):
                    table[label].append(score)
        for pid, mask in masks.items():
            if pid in per_person and mask.any():
                rows = {pid: candidates[RENDER_ROW], person_flat_row(pid): candidates[FLAT_ROW]}
                scores = frame_metrics_against(view.name, list(rows.values()), target, lpips_module,
                                               torch.as_tensor(mask, device=device))
                for label, score in zip(rows, scores, strict=True):
                    per_person[label].append(score)
        full = render_view(view, people, background, render, device)
        composite.append(frame_metrics(view.name, full, target, lpips_module))
    net = lpips_module.net_name
    where = view_set.description
    share = f"{100.0 * float(np.mean(unseen_share)):.1f}%" if unseen_share else "none"
    seen_share = f"{100.0 * (1.0 - float(np.mean(unseen_share))):.1f}%" if unseen_share else "none"
    protocols = {
        "humans": EvalProtocol("ground truth blacked out outside the union of the people's masks; the render shows "
                               "the people only; baselines: nothing rendered, and the fitted bodies drawn flat in "
                               "each person's mean input colour", BLACK, where, net),
        "people": EvalProtocol("each person's own ground-truth mask (frames where it is not empty); the render shows "
                               "every person of the frame, so people in front are accounted for; after each "
                               "person, the fitted bodies drawn flat in each person's mean input colour, in the same "
                               "mask", None, where, net),
        "seen": EvalProtocol("seen pixels: the ground truth's union mask less the never-seen pixels (the table below), "
                             f"on average {seen_share} of it: what the input frames showed, so what the "
                             "reconstruction should reproduce; views without such pixels are skipped", BLACK, where,
                             net),
        "never_seen": EvalProtocol("never-seen pixels: inside the ground truth's union mask, where the nearest surface of "
                                   "the fitted bodies (refined poses) is a triangle none of whose vertices any input "
                                   f"frame saw (stage 06 visibility.npz); on average {share} of the union mask; "
                                   "views without such pixels are skipped", BLACK, where, net),
        "composite": EvalProtocol("none: background and people against the whole frame", None, where, net),
    }
    rows = {"humans": [summarize(label, frames) for label, frames in humans.items() if frames],
            "people": [summarize(label, frames) for label, frames in per_person.items() if frames],
            "seen": [summarize(label, frames) for label, frames in seen.items() if frames],
            "never_seen": [summarize(label, frames) for label, frames in never_seen.items() if frames],
            "composite": [summarize("background + humans", composite)]}
    return EvalTables(rows, protocols)


TITLES = {"humans": "Humans only (GTU protocol)", "people": "Per person",
          "seen": "Seen regions (humans only, restricted to what some input frame saw)",
          "never_seen": "Never-seen regions (humans only, restricted to what no input frame saw)",
          "composite": "Full composite"}


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
    """The humans-only, seen, never-seen and composite means of the render, for the manifest and the demo's
    printout (the humans-only ones only where some view had ground-truth masks)."""
    c = tables.rows["composite"][0]
    values = {"composite_psnr_db": round(c.psnr, 3)}
    if tables.rows["humans"]:
        h = tables.rows["humans"][0]
        values.update(humans_psnr_db=round(h.psnr, 3), humans_ssim=round(h.ssim, 4),
                      humans_lpips_x100=round(h.lpips, 3))
    for name in ("seen", "never_seen"):
        if tables.rows[name]:
            row = tables.rows[name][0]
            values.update({f"{name}_psnr_db": round(row.psnr, 3), f"{name}_lpips_x100": round(row.lpips, 3)})
    return values
