"""The report's sections, each built from the run record: HTML text, with the pictures it needs written into
the page folder through ``Assets``. A section whose stage has not run says so instead."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from glimpse.config import STAGE_NAMES
from glimpse.io.cameras_json import read_cameras_json
from glimpse.io.images import frame_files, frame_name, read_mask, read_rgb, write_png
from glimpse.report import figures
from glimpse.report.config import ReportConfig
from glimpse.report.html import esc, image, markdown, table, video
from glimpse.report.run_record import LOG_FILE, RunRecord, changed_params, warnings_in_log


@dataclass
class Assets:
    """Where the page's pictures go: ``folder`` on disk, referenced from the page as ``href/<name>``."""

    folder: Path
    href: str
    config: ReportConfig

    def path(self, name: str) -> Path:
        return self.folder / name

    def link(self, name: str) -> str:
        return f"{self.href}/{name}"

    def still(self, name: str, rgb: np.ndarray) -> str:
        """Write a still scaled to the configured height; its link."""
        write_png(self.path(name), figures.scaled_to_height(rgb, self.config.still_height_px))
        return self.link(name)


def not_run(stage: str) -> str:
    return f'<p class="muted">Stage {esc(stage)} has not run in this folder.</p>'


def run_link(record: RunRecord, path: Path) -> str:
    """``path`` relative to the run folder (where report.html is), as a link."""
    return path.relative_to(record.root).as_posix()


def headline(record: RunRecord) -> str:
    """One line of the numbers that matter, from stage 07's summary (or what the last stage reported)."""
    s = record.summary("07_eval")
    if not s:
        return '<p class="headline">No metrics yet: stage 07_eval has not run.</p>'
    parts = [f"humans only (held-out): PSNR {s['humans_psnr_db']:.2f} dB, SSIM {s['humans_ssim']:.4f}, "
             f"LPIPS×100 {s['humans_lpips_x100']:.2f}"] if "humans_psnr_db" in s else []
    for key, words in (("seen", "seen regions"), ("never_seen", "never-seen regions")):
        if f"{key}_psnr_db" in s:
            parts.append(f"{words}: PSNR {s[f'{key}_psnr_db']:.2f} dB, LPIPS×100 {s[f'{key}_lpips_x100']:.2f}")
    parts.append(f"full frame: PSNR {s['composite_psnr_db']:.2f} dB")
    views = f"{s.get('view_count', '?')} {s.get('views', '')} views"
    return (f'<p class="headline">{esc("; ".join(parts))}.<br><span class="muted">{esc(views)}, prior '
            f'{esc(s.get("prior", "?"))}.</span></p>')


def scene_section(record: RunRecord) -> str:
    if not record.has("01_sfm"):
        return not_run("01_sfm")
    cameras = record.reports.get("01_sfm", {})
    width, height, frames = read_cameras_json(record.stage_dir("01_sfm") / "cameras.json")
    facts: list[tuple[str, Any]] = [
        ("scene folder", record.manifests["01_sfm"].get("scene", "?")),
        ("frames with a camera", f"{len(frames)} of {cameras.get('frames', len(frames))}"),
        ("image size", f"{width} × {height} pixels"),
        ("cameras", f"{cameras.get('mode', '?')} ({cameras.get('mode_reason', '')}); camera "
                    f"{cameras.get('camera_motion', '?')}; units {cameras.get('units', '?')}"),
    ]
    if cameras.get("sfm"):
        facts.append(("structure from motion", ", ".join(f"{k} {v}" for k, v in cameras["sfm"].items()
                                                         if not isinstance(v, (dict, list)))))
    for warning in cameras.get("warnings", []):
        facts.append(("warning", warning))
    if record.has("07_eval"):
        facts.append(("scored views", record.reports.get("07_eval", {}).get("views", "?")))
    html = table(None, facts)
    fit = record.summary("02_smpl_fit")
    people = record.reports.get("06_joint_opt", {}).get("people", {})
    pids = sorted(set(fit.get("modes", {})) | set(people))
    if pids:
        rows = []
        for pid in pids:
            residual = fit.get("keypoint_residuals", {}).get(pid, {})
            trained = people.get(pid, {})
            rows.append([pid, fit.get("modes", {}).get(pid, "–"), residual.get("keypoints2d_residual_px"),
                         residual.get("keypoints3d_residual_m"), trained.get("frames"), trained.get("gaussians"),
                         trained.get("body_vertices_seen")])
        html += "<h3>People</h3>" + table(
            ["person", "body fitted from", "2D keypoint residual (px)", "3D keypoint residual (m)", "frames",
             "Gaussians", "body surface seen (share)"], rows)
    if "ground" in fit:
        ground = ", ".join(f"{key} {value}" for key, value in fit["ground"].items())
        html += f'<p class="muted">Ground plane (stage 02): {esc(ground)}</p>'
    return html


def metrics_section(record: RunRecord, assets: Assets) -> str:
    if not record.has("07_eval"):
        return not_run("07_eval")
    out = record.stage_dir("07_eval")
    tables = record.reports.get("07_eval", {}).get("tables", {})
    html = seen_beside_never_seen(tables)
    html += markdown((out / "metrics.md").read_text()) if (out / "metrics.md").is_file() else ""
    humans = tables.get("humans", {}).get("rows", [])
    if humans and humans[0].get("frames"):
        names = [f["frame"] for f in humans[0]["frames"]]
        series = [(row["label"], list(range(len(names))), [f["psnr"] for f in row["frames"]]) for row in humans]
        figures.line_plot(assets.path("scored_views_psnr.png"), assets.config, "Humans-only PSNR per scored view",
                          "scored view (camera/frame, in the order of metrics.json)", "PSNR (dB)", series,
                          markers=True)
        html += image(assets.link("scored_views_psnr.png"),
                      f"Per view: {names[0]} … {names[-1]}; the render against both baselines")
    if (out / "speed.md").is_file():
        html += markdown((out / "speed.md").read_text())
    return html


def seen_beside_never_seen(tables: dict) -> str:
    """The seen and never-seen tables side by side, one row per candidate (the render, then the baselines):
    what the reconstruction reproduced next to what the prior guessed. Empty when neither table exists."""
    seen = {row["label"]: row for row in tables.get("seen", {}).get("rows", [])}
    unseen = {row["label"]: row for row in tables.get("never_seen", {}).get("rows", [])}
    if not seen and not unseen:
        return ""
    labels = list(seen) + [label for label in unseen if label not in seen]

    def cells(row: dict | None) -> list[object]:
        return [row["psnr"], row["ssim"], row["lpips"]] if row else ["-", "-", "-"]

    rows = [[label, *cells(seen.get(label)), *cells(unseen.get(label))] for label in labels]
    headers = ["", "seen PSNR (dB)", "seen SSIM", "seen LPIPS×100", "never-seen PSNR (dB)", "never-seen SSIM",
               "never-seen LPIPS×100"]
    return ("<h3>Seen and never-seen regions of the people</h3>" + table(headers, rows, decimals=3)
            + '<p class="muted">Seen: the people\'s pixels whose body surface some input frame showed (what the '
              "reconstruction reproduces); never seen: those no input frame showed (what the prior guesses). "
              "Protocols in the tables below.</p>")


def _video_stills(assets: Assets, path: Path, stem: str, caption: str) -> str:
    stills = figures.video_stills(path, assets.config.stills)
    pictures = "".join(image(assets.still(f"{stem}_{index:04d}.png", rgb), f"{caption}, frame {index}")
                       for index, rgb in stills)
    return f"<div>{pictures}</div>"


def heldout_section(record: RunRecord, assets: Assets) -> str:
    if not record.has("07_eval"):
        return not_run("07_eval")
    renders = record.summary("07_eval").get("renders", {})
    names = sorted(name for name in renders if name.startswith(("heldout_", "input.")))
    if not names:
        return '<p class="muted">Stage 07 wrote no render videos (07_eval.renders.enabled is false).</p>'
    html = ""
    for name in names:
        path = record.stage_dir("07_eval") / "renders" / name
        html += f"<h3>{esc(renders[name])}</h3>" + _video_stills(assets, path, Path(name).stem, renders[name])
    return html


def training_section(record: RunRecord, assets: Assets) -> str:
    background, joint = record.reports.get("04_bg_pretrain"), record.reports.get("06_joint_opt")
    if not background and not joint:
        return not_run("04_bg_pretrain")
    html, config = "", assets.config
    if background and background.get("loss_history"):
        steps, values = zip(*background["loss_history"])
        figures.line_plot(assets.path("loss_background.png"), config, "Stage 04: background loss", "iteration",
                          "loss", [("loss", steps, values)], log_y=True)
        html += image(assets.link("loss_background.png"), "Background pre-training: loss (L1 + D-SSIM, people "
                                                          "masked out) over iterations")
    if joint and joint.get("loss_history"):
        history = joint["loss_history"]
        terms = [k for k in history[0] if k != "iteration" and any(e.get(k, 0) > 0 for e in history)]
        series = [(k, [e["iteration"] for e in history], [max(e.get(k, 0.0), 1e-12) for e in history])
                  for k in terms]
        figures.line_plot(assets.path("loss_joint.png"), config, "Stage 06: loss terms", "iteration",
                          "value (log scale)", series, log_y=True)
        html += image(assets.link("loss_joint.png"), "Joint optimisation: every loss term that was ever non-zero")
    counts = _gaussian_counts(background, joint)
    if counts:
        figures.line_plot(assets.path("gaussians.png"), config, "Gaussians over iterations", "iteration",
                          "Gaussians", counts, markers=True)
        html += image(assets.link("gaussians.png"), "Gaussian counts at each densification or pruning step "
                                                    "(stage 04: background; stage 06: each person)")
    series = _input_psnr(background, joint)
    if series:
        figures.line_plot(assets.path("input_psnr.png"), config, "PSNR on the input frames", "frame", "PSNR (dB)",
                          series, markers=True)
        html += image(assets.link("input_psnr.png"), "Per input frame: the background where no person is "
                                                     "(stage 04), the whole frame and the people's pixels (stage 06)")
    rows = []
    for stage, report in (("04_bg_pretrain", background), ("06_joint_opt", joint)):
        if report:
            rows.append([stage, report.get("iterations"), report.get("iterations_per_s"), report.get("training_s"),
                         report.get("resumed_from_iteration")])
    html += table(["stage", "iterations", "iterations per second", "training (s)", "resumed from iteration"], rows)
    return html


def _gaussian_counts(background: dict | None, joint: dict | None) -> list[figures.Series]:
    series = []
    if background and background.get("densify_events"):
        events = background["densify_events"]
        series.append(("background (04)", [e["iteration"] for e in events], [e["count"] for e in events]))
    if joint and joint.get("densify_events"):
        for pid, person in sorted(joint.get("people", {}).items()):
            events = [e for e in joint["densify_events"] if e.get("person") == pid]
            xs = [0] + [e["iteration"] for e in events]
            ys = [person.get("gaussians_initial", events[0]["count"] if events else 0)] + [e["count"] for e in events]
            series.append((f"{pid} (06)", xs, ys))
    return series


def _input_psnr(background: dict | None, joint: dict | None) -> list[figures.Series]:
    series = []
    for report, key, label in ((background, "psnr_background_db", "background, no person (04)"),
                               (joint, "psnr_db", "whole frame (06)"), (joint, "psnr_people_db", "people (06)")):
        frames = (report or {}).get("frames", {})
        points = [(int(name), entry[key]) for name, entry in sorted(frames.items())
                  if entry.get(key) is not None and np.isfinite(entry[key])]
        if points:
            series.append((label, *zip(*points)))
    return series


def bodies_section(record: RunRecord, assets: Assets) -> str:
    overlay = record.stage_dir("02_smpl_fit") / "overlay.mp4"
    if not record.has("02_smpl_fit"):
        return not_run("02_smpl_fit")
    if not overlay.is_file():
        return '<p class="muted">Stage 02 wrote no overlay video.</p>'
    return ("<p>The fitted bodies drawn over the input frames (stage 02).</p>"
            + _video_stills(assets, overlay, "bodies", "bodies over the input") + video(
                run_link(record, overlay), "the fitted bodies over the whole input video",
                assets.config.still_height_px))


def masks_section(record: RunRecord, assets: Assets) -> str:
    if not record.has("03_masks") or not record.has("01_sfm"):
        return not_run("03_masks")
    index = record.reports.get("03_masks", {})
    pids = index.get("people", [])
    frames = frame_files(record.stage_dir("01_sfm") / "frames")
    ids = sorted(frames)
    legend = ", ".join(f'<span style="color: rgb{figures.person_colour(i)}">■</span> {esc(pid)}'
                       for i, pid in enumerate(pids))
    pictures = []
    for position in figures.spread_indices(len(ids), assets.config.stills):
        fid = ids[position]
        masks = []
        for pid in pids:
            path = record.stage_dir("03_masks") / "masks" / pid / f"{frame_name(fid)}.png"
            masks.append(read_mask(path) if path.is_file() else None)
        still = figures.mask_overlay(read_rgb(frames[fid]), masks, assets.config.mask_opacity)
        order = index.get("frames", {}).get(frame_name(fid), {}).get("depth_order", [])
        pictures.append(image(assets.still(f"masks_{frame_name(fid)}.png", still),
                              f"frame {fid}; front to back: {', '.join(order) or '–'}"))
    return (f"<p>Each person's visible mask (stage 03, mode {esc(index.get('mode', '?'))}): {legend}</p>"
            + "".join(pictures))


def videos_section(record: RunRecord, config: ReportConfig) -> str:
    described = {f"07_eval/renders/{name}": text for name, text in record.summary("07_eval").get("renders", {}).items()}
    described.update({"04_bg_pretrain/renders/background.mp4": "the background after pre-training (stage 04)",
                      "06_joint_opt/renders/joint.mp4": "the scene after joint optimisation (stage 06), input view"})
    found = []
    for stage in ("04_bg_pretrain", "06_joint_opt", "07_eval"):
        found += sorted((record.stage_dir(stage) / "renders").glob("*.mp4")) if record.has(stage) else []
    if not found:
        return '<p class="muted">No videos yet.</p>'
    return "".join(video(run_link(record, path), described.get(run_link(record, path), path.name),
                         config.still_height_px) for path in found)


def parameters_section(record: RunRecord, defaults: dict[str, Any]) -> str:
    html = ""
    for stage, manifest in record.manifests.items():
        changes = changed_params(manifest.get("params", {}), defaults)
        if changes:
            rows = [[key, repr(value), repr(default) if default is not None else "(not in pipeline.yaml)"]
                    for key, value, default in changes]
            html += f"<h3>{esc(stage)}</h3>" + table(["parameter", "this run", "pipeline.yaml default"], rows)
    return html or "<p>Every stage ran with the defaults of pipeline.yaml.</p>"


def timings_section(record: RunRecord, assets: Assets) -> str:
    stages = list(record.manifests)
    phases = sorted({k for m in record.manifests.values() for k in m.get("timings_s", {}) if k != "total"})
    stacks: dict[str, list[float]] = {p: [] for p in phases + ["other"]}
    rows = []
    for stage in stages:
        timings = record.manifests[stage].get("timings_s", {})
        total = float(timings.get("total", 0.0))
        for phase in phases:
            stacks[phase].append(float(timings.get(phase, 0.0)))
        stacks["other"].append(max(0.0, total - sum(float(timings.get(p, 0.0)) for p in phases)))
        rows.append([stage, total, ", ".join(f"{k} {v:.1f} s" for k, v in timings.items() if k != "total"),
                     record.manifests[stage].get("finished_at", "?")])
    stacks = {name: values for name, values in stacks.items() if any(v > 0 for v in values)}
    figures.bar_plot(assets.path("timings.png"), assets.config, "Time per stage", "seconds", stages, stacks)
    total = sum(row[1] for row in rows)
    return (table(["stage", "seconds", "phases", "finished"], rows + [["all stages", total, "", ""]], decimals=1)
            + image(assets.link("timings.png"), "Seconds per stage, by phase"))


def logs_section(record: RunRecord, config: ReportConfig) -> str:
    html = ""
    for stage in STAGE_NAMES:
        log = record.stage_dir(stage) / LOG_FILE
        if record.has(stage) and log.is_file():
            lines = warnings_in_log(log, config.log_lines)
            html += f'<p><a href="{esc(run_link(record, log))}">{esc(stage)}/{LOG_FILE}</a>'
            html += (f'<pre class="warn">{esc(chr(10).join(lines))}</pre>' if lines else " (no warnings)") + "</p>"
        if stage in record.failed_logs:
            failed = record.failed_logs[stage]
            html += (f'<p class="warn">Last failed attempt of {esc(stage)}: '
                     f'<a href="{esc(run_link(record, failed))}">{esc(failed.name)}</a></p>')
    return html or '<p class="muted">No logs.</p>'
