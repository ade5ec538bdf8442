"""Judging stage 04 against a synthetic scene's ground truth (glimpse.fixtures): the background
Gaussians rendered from each input camera against the place rendered without its people by the
mesh renderer (``<scene>.groundtruth/background/``), on three kinds of pixels:

- *visible*: no person covers them in that frame and the stage reports them seen (the rest of
  the visible pixels, hidden by the stage's grown masks in every frame, are never trained on:
  their share is ``visible_reported_never_seen_fraction``);
- *behind people*: a person covers them in that frame and the stage reports them seen (not in
  its ``never_seen/`` masks). A ghost (a person baked into the background) shows here; the
  input frame itself scores what a complete ghost would (``psnr_frame_behind_people_db``);
- *never seen*: people cover them in every frame (static camera only). The stage must report
  them (recall); it may report more, as its masks are grown (its reported fraction is given).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from glimpse.cameras.model import render_camera
from glimpse.config import config_from_mapping
from glimpse.gaussians.model import GaussianModel
from glimpse.gaussians.ply import read_gaussians_ply
from glimpse.io.cameras_json import read_cameras_json
from glimpse.io.images import frame_files, frame_name, read_mask, read_rgb
from glimpse.metrics.image import psnr
from glimpse.render import RenderConfig, rasterize

REPORT_KEYS = {"visible": "psnr_visible_db", "behind": "psnr_behind_people_db",
               "frame_behind": "psnr_frame_behind_people_db"}


def _people(scene: Path, fid: int) -> np.ndarray:
    masks = [read_mask(path) for path in sorted((scene / "humans").glob(f"*/masks/{frame_name(fid)}.png"))]
    return np.logical_or.reduce(masks)


def _psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float | None:
    if not mask.any():
        return None
    return float(psnr(torch.as_tensor(a / 255.0), torch.as_tensor(b / 255.0), torch.as_tensor(mask)))


def stage_render_settings(stage_dir: Path) -> RenderConfig:
    """The ``render`` section a finished stage ran with (its manifest's parameters)."""
    manifest = stage_dir / "manifest.json"
    return config_from_mapping(RenderConfig, json.loads(manifest.read_text())["params"]["render"], f"{manifest} render")


def judge_background(stage_dir: Path, sfm_dir: Path, scene: Path, static_camera: bool) -> dict:
    """Mean PSNRs (dB) over frames on each kind of pixel, and the never-seen recall (static camera), of stage 04's
    background drawn with the render settings the stage ran with."""
    render = stage_render_settings(stage_dir)
    truth_dir = scene.with_name(scene.name + ".groundtruth") / "background"
    model = GaussianModel.from_splats(read_gaussians_ply(stage_dir / "background.ply")[0])
    width, height, cameras = read_cameras_json(sfm_dir / "cameras.json")
    frames = frame_files(sfm_dir / "frames")
    people = {fid: _people(scene, fid) for fid in cameras}
    never_truth = np.logical_and.reduce(list(people.values())) if static_camera else None
    scores: dict[str, list[float]] = {"visible": [], "behind": [], "frame_behind": []}
    never_found, visible_unseen = [], []
    for fid, camera in sorted(cameras.items()):
        with torch.no_grad():
            out = rasterize(render_camera(camera, torch.device("cpu")), **model.render_inputs(), settings=render)
        rendered = (out.rgb.clamp(0, 1) * 255).round().numpy()
        truth = read_rgb(truth_dir / f"{frame_name(fid)}.png").astype(np.float64)
        found = read_mask(stage_dir / "never_seen" / f"{frame_name(fid)}.png")
        never_found.append(found)
        behind = people[fid] & ~found
        visible_unseen.append(float((~people[fid] & found).sum() / max((~people[fid]).sum(), 1)))
        for key, value in (("visible", _psnr(rendered, truth, ~people[fid] & ~found)),
                           ("behind", _psnr(rendered, truth, behind)),
                           ("frame_behind", _psnr(read_rgb(frames[fid]).astype(np.float64), truth, behind))):
            if value is not None:
                scores[key].append(value)
    doc = {REPORT_KEYS[k]: (round(float(np.mean(v)), 3) if v else None) for k, v in scores.items()}
    doc["visible_reported_never_seen_fraction"] = round(float(np.mean(visible_unseen)), 5)
    if never_truth is not None:
        found_all = np.logical_and.reduce(never_found)
        doc["never_seen_truth_fraction"] = round(float(never_truth.mean()), 5)
        doc["never_seen_reported_fraction"] = round(float(found_all.mean()), 5)
        doc["never_seen_recall"] = (round(float((found_all & never_truth).sum() / never_truth.sum()), 4)
                                    if never_truth.any() else None)
    return doc
