"""Stage 04's logic: training views from stage 01's frames and stage 03's union masks, the initial
cloud (SfM points or the sphere), training with checkpoints, then the never-seen analysis, the
renders and the report. The stage's run.py only parses, loads and writes what this returns."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from glimpse.background.config import BackgroundConfig
from glimpse.background.evaluate import render_views, seen_weights
from glimpse.background.init import InitialCloud, Sphere, colour_from_frames, sphere_points
from glimpse.background.train import BackgroundTrainer, TrainingView
from glimpse.body.params import BodyParams
from glimpse.cameras.model import PinholeCamera, render_camera
from glimpse.errors import GlimpseError
from glimpse.gaussians.density import keep_only
from glimpse.gaussians.model import GaussianModel, knn_scales
from glimpse.gaussians.trainer import TrainingLog
from glimpse.gaussians.training import scene_extent
from glimpse.io.frame_cache import FrameCache, FrameCacheSize
from glimpse.io.images import frame_files, frame_name, read_mask, read_rgb, write_png
from glimpse.io.ply_points import read_points_ply
from glimpse.io.video import write_mp4
from glimpse.morphology import disk
from glimpse.render.config import RenderConfig

INIT_FORMAT = "glimpse-bg-init/1"
REPORT_FORMAT = "glimpse-bg-report/1"
SCALE_FLOOR_FRACTION = 1e-4  # initial Gaussian scales are at least this fraction of the scene extent


@dataclass(frozen=True)
class BackgroundInputs:
    cameras: dict[int, PinholeCamera]  # stage 01's, per frame id
    width: int
    height: int
    frames_dir: Path  # stage 01's frames/
    union_dir: Path  # stage 03's masks/union/
    points_ply: Path | None  # stage 01's points.ply (absent for a static camera)
    bodies: dict[str, BodyParams]  # stage 02's
    fps: float


def load_views(inputs: BackgroundInputs, config: BackgroundConfig, device: torch.device, frames: FrameCacheSize
               ) -> tuple[list[TrainingView], FrameCache]:
    """Every frame with a camera, and the cache its pixels are read through: the image, and its background =
    not in stage 03's union mask grown by human_mask_dilate_px."""
    files = frame_files(inputs.frames_dir)
    unions = {fid: inputs.union_dir / f"{frame_name(fid)}.png" for fid in inputs.cameras}
    for fid in sorted(inputs.cameras):
        if fid not in files or not unions[fid].is_file():
            raise GlimpseError(f"04_bg_pretrain: frame {frame_name(fid)} has a camera but no "
                               f"{'frame in ' + str(inputs.frames_dir) if fid not in files else unions[fid]}; "
                               f"rerun stages 01 and 03")
    if not inputs.cameras:
        raise GlimpseError("04_bg_pretrain: no frame has a camera (stage 01's cameras.json is empty)")

    def read(fid: int) -> tuple[torch.Tensor, torch.Tensor]:
        people = disk(read_mask(unions[fid]), config.human_mask_dilate_px)
        return torch.as_tensor(read_rgb(files[fid]), device=device), torch.as_tensor(~people, device=device)

    cache = FrameCache(read, frames.frames)
    views = [TrainingView(fid, render_camera(inputs.cameras[fid], device), cache.get) for fid in sorted(inputs.cameras)]
    return views, cache


def people_sphere(inputs: BackgroundInputs, radius_m: float) -> Sphere:
    """Centre: the mean of every body's translation over its frames; radius in world units (metres
    times the people's mean scale, world units per metre)."""
    if not inputs.bodies:
        raise GlimpseError("04_bg_pretrain: the sphere is centred on the people, but stage 02 fitted no body")
    centre = np.concatenate([b.transl for b in inputs.bodies.values()]).mean(0)
    scale = float(np.mean([b.scale for b in inputs.bodies.values()]))
    return Sphere(centre, radius_m * scale)


def choose_init(inputs: BackgroundInputs, config: BackgroundConfig) -> str:
    if config.init == "points" and inputs.points_ply is None:
        raise GlimpseError("04_bg_pretrain.init=points needs stage 01's points.ply, which a static camera does not "
                           "have; use init: sphere or auto")
    if config.init == "auto":
        return "points" if inputs.points_ply is not None else "sphere"
    return config.init


def initial_cloud(inputs: BackgroundInputs, config: BackgroundConfig, views: list[TrainingView]
                  ) -> tuple[InitialCloud, Sphere | None, dict]:
    kind = choose_init(inputs, config)
    if kind == "points":
        xyz, rgb = read_points_ply(inputs.points_ply)
        if len(xyz) < 2:
            raise GlimpseError(f"{inputs.points_ply}: {len(xyz)} points, too few to start the background from; "
                               f"use 04_bg_pretrain.init=sphere")
        cloud = InitialCloud(xyz.astype(np.float64), rgb / 255.0, np.ones(len(xyz), bool))
        return cloud, None, {"kind": "points", "source": "01_sfm/points.ply", "points": len(xyz)}
    sphere = people_sphere(inputs, config.sphere_radius_m)
    cameras = [inputs.cameras[v.frame_id] for v in views]
    points = sphere_points(sphere, cameras, inputs.width, inputs.height, config.sphere_spacing_px)
    picks = np.unique(np.linspace(0, len(views) - 1, min(config.init_colour_frames, len(views))).round().astype(int))
    samples = [(cameras[k], views[k].image.cpu().numpy(), views[k].background.cpu().numpy()) for k in picks]
    rgb, seen = colour_from_frames(points, samples)
    doc = {"kind": "sphere", "centre": sphere.centre.tolist(), "radius": sphere.radius,
           "radius_m": config.sphere_radius_m, "spacing_px": config.sphere_spacing_px, "points": len(points),
           "colour_frames": len(picks), "points_never_seen": int((~seen).sum())}
    return InitialCloud(points, rgb, seen), sphere, doc


def initial_model(cloud: InitialCloud, config: BackgroundConfig, sh_degree: int, extent: float,
                  device: torch.device) -> GaussianModel:
    scales = knn_scales(cloud.points, config.points_knn, SCALE_FLOOR_FRACTION * extent)
    model = GaussianModel.from_points(torch.as_tensor(cloud.points, dtype=torch.float32),
                                      torch.as_tensor(cloud.rgb, dtype=torch.float32),
                                      torch.as_tensor(scales, dtype=torch.float32), config.initial_opacity, sh_degree)
    return model.to(device)


@dataclass
class BackgroundResult:
    model: GaussianModel
    init_doc: dict
    report: dict


def train_background(inputs: BackgroundInputs, config: BackgroundConfig, render: RenderConfig, seed: int,
                     device: torch.device, frames: FrameCacheSize, work: Path, key: str, out: Path
                     ) -> BackgroundResult:
    """The whole stage: writes renders/ and never_seen/ under ``out``; returns the model and documents."""
    views, cache = load_views(inputs, config, device, frames)
    cloud, sphere, init_doc = initial_cloud(inputs, config, views)
    extent = scene_extent([v.camera for v in views], torch.as_tensor(cloud.points, dtype=torch.float32, device=device))
    model = initial_model(cloud, config, render.sh_degree, extent, device)
    init_doc = {"format": INIT_FORMAT, **init_doc, "extent": extent, "initial_gaussians": len(model)}
    trainer = BackgroundTrainer(model, views, config, render, sphere, seed, work / "checkpoint.pt", key)
    trainer.read_ahead(cache.prefetch, frames.read_ahead)
    training = trainer.run()
    model = trainer.model
    seen = seen_weights(model, views, render) >= config.never_seen_min_weight
    pruned_unseen = 0
    if config.never_seen == "prune":
        pruned_unseen = int((~seen).sum())
        keep_only(model, trainer.optimizer, seen)
        seen = seen[seen]
    report = _write_views(model, views, render, config, inputs.fps, out)
    cache.close()
    report.update(_training_doc(training, config, len(model), int((~seen).sum()), pruned_unseen))
    return BackgroundResult(model, init_doc, report)


def _write_views(model: GaussianModel, views: list[TrainingView], render: RenderConfig,
                 config: BackgroundConfig, fps: float, out: Path) -> dict:
    """Render every input view once (streamed: the video never holds all frames in memory)."""
    frames_doc: dict[str, dict] = {}
    always: np.ndarray | None = None  # pixels never seen in each frame so far

    def renders():
        nonlocal always
        for result in render_views(model, views, render):
            always = result.never_seen if always is None else always & result.never_seen
            write_png(out / "never_seen" / f"{frame_name(result.frame_id)}.png", result.never_seen)
            frames_doc[frame_name(result.frame_id)] = {"psnr_background_db": round(result.psnr_background_db, 3),
                                                       "never_seen_fraction": round(float(result.never_seen.mean()), 5)}
            yield result.render

    if config.render_video:
        write_mp4(out / "renders" / "background.mp4", renders(), fps)
    else:
        for _ in renders():
            pass
    values = [f["psnr_background_db"] for f in frames_doc.values() if np.isfinite(f["psnr_background_db"])]
    return {"format": REPORT_FORMAT, "psnr_background_db": round(float(np.mean(values)), 3) if values else None,
            "never_seen_fraction_mean": round(float(np.mean([f["never_seen_fraction"] for f in frames_doc.values()])), 5),
            "never_seen_in_every_frame_fraction": round(float(always.mean()), 5), "frames": frames_doc}


def _training_doc(training: TrainingLog, config: BackgroundConfig, count: int, unseen: int, pruned: int) -> dict:
    return {"iterations": config.total_iterations, "resumed_from_iteration": training.resumed_from,
            "iterations_per_s": round(training.iterations_per_s, 3), "training_s": round(training.seconds, 2),
            "phase_seconds": training.phase_seconds,
            "gaussians": count, "gaussians_never_seen": unseen, "never_seen_pruned": pruned,
            "densify_events": training.densify_events, "loss_history": training.losses}

