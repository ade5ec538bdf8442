"""Stage 06's logic: training views from stage 01's frames and stage 03's masks, people initialised
on their canonical bodies, the background from stage 04, joint training with checkpoints, then the
renders and the report. The stage's run.py only parses, loads and writes what this returns."""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from glimpse.body.config import BodyConfig
from glimpse.body.models import BodyModels
from glimpse.body.params import BodyParams
from glimpse.cameras.model import PinholeCamera, render_camera
from glimpse.errors import GlimpseError
from glimpse.gaussians.model import GaussianModel
from glimpse.gaussians.trainer import TrainingLog
from glimpse.humans.compose import frame_gaussians, render_frame
from glimpse.humans.person import PersonGaussians, initial_person
from glimpse.humans.visibility import BodyVisibility, body_visibility
from glimpse.io.frame_cache import FrameCache, FrameCacheSize
from glimpse.io.images import frame_files, frame_name, read_mask, read_rgb
from glimpse.io.video import write_mp4
from glimpse.joint.config import JointConfig
from glimpse.joint.train import Box, JointTrainer, JointView, people_box
from glimpse.metrics.image import psnr
from glimpse.metrics.lpips import LPIPS
from glimpse.prior import PriorContext, make_prior
from glimpse.render.config import RenderConfig

REPORT_FORMAT = "glimpse-joint-report/1"
PREVIEWS_DIR = "sds_previews"  # <pid>/<iteration>.png, when the sds prior is asked for previews


@dataclass(frozen=True)
class JointInputs:
    cameras: dict[int, PinholeCamera]  # stage 01's, per frame id
    width: int
    height: int
    frames_dir: Path  # stage 01's frames/
    masks_dir: Path  # stage 03's masks/ (union/ and one folder per person)
    occluders_dir: Path  # stage 03's occluders/
    bodies: dict[str, BodyParams]  # stage 02's
    background: GaussianModel  # stage 04's
    fps: float


@dataclass
class JointResult:
    background: GaussianModel
    people: list[PersonGaussians]
    visibility: dict[str, BodyVisibility]  # per pid: what the input frames saw of the fitted body
    report: dict


def static_occlusion(union: np.ndarray, occluders: list[np.ndarray]) -> np.ndarray:
    """[H, W] bool: pixels where some person's body is hidden by something that is not a person (static
    geometry): the union of the occluder masks outside every person's visible mask. A person hidden by
    another person needs no exclusion: both are in the render, in depth order."""
    hidden = np.zeros_like(union, dtype=bool)
    for mask in occluders:
        hidden |= mask
    return hidden & ~union


def load_views(inputs: JointInputs, config: JointConfig, device: torch.device, frames: FrameCacheSize
               ) -> tuple[list[JointView], FrameCache]:
    """Every frame with a camera, and the cache its pixels are read through; the losses skip pixels a static
    occluder hides (docs/joint.md)."""
    files = frame_files(inputs.frames_dir)
    for fid in sorted(inputs.cameras):
        union_path = inputs.masks_dir / "union" / f"{frame_name(fid)}.png"
        if fid not in files or not union_path.is_file():
            raise GlimpseError(f"06_joint_opt: frame {frame_name(fid)} has a camera but no "
                               f"{'frame in ' + str(inputs.frames_dir) if fid not in files else union_path}; "
                               f"rerun stages 01 and 03")
    if not inputs.cameras:
        raise GlimpseError("06_joint_opt: no frame has a camera (stage 01's cameras.json is empty)")

    def read(fid: int) -> tuple[torch.Tensor, torch.Tensor, Box | None, dict]:
        name = frame_name(fid)
        union = read_mask(inputs.masks_dir / "union" / f"{name}.png")
        occluders = [read_mask(path) for pid in inputs.bodies
                     if (path := inputs.occluders_dir / pid / f"{name}.png").is_file()]
        keep = ~static_occlusion(union, occluders)
        box = people_box(union, config.loss.lpips_margin_px, config.loss.lpips_min_px)
        return torch.as_tensor(read_rgb(files[fid]), device=device), torch.as_tensor(keep, device=device), box, {}

    cache = FrameCache(read, frames.frames)
    views = [JointView(fid, render_camera(inputs.cameras[fid], device), cache.get) for fid in sorted(inputs.cameras)]
    return views, cache


class PersonMasks(Mapping[int, dict[str, np.ndarray]]):
    """frame id (with a camera) -> person -> stage 03's visible mask [H, W] bool, for the people with a mask
    file there; read when asked, never held (a long video's masks need no memory)."""

    def __init__(self, inputs: JointInputs, pids: list[str]):
        self.inputs, self.pids = inputs, pids

    def __getitem__(self, fid: int) -> dict[str, np.ndarray]:
        if fid not in self.inputs.cameras:
            raise KeyError(fid)
        paths = {pid: self.inputs.masks_dir / pid / f"{frame_name(fid)}.png" for pid in self.pids}
        return {pid: read_mask(path) for pid, path in paths.items() if path.is_file()}

    def __iter__(self) -> Iterator[int]:
        return iter(sorted(self.inputs.cameras))

    def __len__(self) -> int:
        return len(self.inputs.cameras)


def initial_people(inputs: JointInputs, config: JointConfig, body: BodyConfig, body_models: BodyModels,
                   sh_degree: int, device: torch.device) -> list[PersonGaussians]:
    """One PersonGaussians per person with a body in some frame with a camera, in pid order."""
    people = []
    for pid in sorted(inputs.bodies):
        params = inputs.bodies[pid].select(sorted(inputs.cameras))
        if len(params.frame_ids) == 0:
            continue
        person = initial_person(pid, body_models[pid], params, body.canonical_hip_angle_deg, body.skinning,
                                config.initial_grey, config.initial_opacity, config.initial_scale_knn, sh_degree)
        people.append(person.to(device))
    return people


def train_joint(inputs: JointInputs, config: JointConfig, render: RenderConfig, body: BodyConfig,
                body_models: BodyModels, prior_kind: str, prior_config: object | None, seed: int, device: torch.device,
                frames: FrameCacheSize, work: Path, key: str, out: Path, identity_dir: Path | None = None
                ) -> JointResult:
    """Train with the prior ``prior_kind`` (built with ``prior_config``, its section's typed config; ``identity_dir``
    stage 05's outputs), then render every input view (``out/renders/joint.mp4``) and build the report; the sds
    prior writes its previews, when asked, to ``out/sds_previews/``."""
    torch.manual_seed(seed)
    views, cache = load_views(inputs, config, device, frames)
    people = initial_people(inputs, config, body, body_models, render.sh_degree, device)
    visibility = body_visibility(body_models, {p.pid: p.body for p in people}, inputs.cameras, inputs.width,
                                 inputs.height, PersonMasks(inputs, [p.pid for p in people]), config.visibility)
    prior = make_prior(prior_kind, PriorContext(people, visibility, body_models, render, seed, config.scaled,
                                                identity_dir, out / PREVIEWS_DIR), prior_config)
    initial_counts = {p.pid: len(p.model) for p in people}
    background = inputs.background.to(device)
    lpips_module = LPIPS(config.loss.lpips_net).to(device) if config.loss.lpips > 0 else None
    trainer = JointTrainer(background, people, views, config, render, prior, lpips_module, seed,
                           work / "checkpoint.pt", key, frames.derived_mb)
    trainer.read_ahead(cache.prefetch, frames.read_ahead)
    training = trainer.run()
    frames_doc = _write_views(trainer, views, config, inputs, out)
    cache.close()
    report = _report(training, config, people, initial_counts, frames_doc, prior.name)
    report.update({f"prior_{key}": value for key, value in prior.report().items()})
    for person in people:
        report["people"][person.pid]["body_vertices_seen"] = round(float(visibility[person.pid].seen.mean()), 4)
    return JointResult(background, people, visibility, report)


@torch.no_grad()
def _write_views(trainer: JointTrainer, views: list[JointView], config: JointConfig, inputs: JointInputs,
                 out: Path) -> dict:
    """Render each input view once; PSNR on the people's pixels (stage 03's union mask) per frame."""
    frames_doc: dict[str, dict] = {}
    degree = trainer.render.sh_degree

    def renders():
        for view in views:
            gaussians = frame_gaussians(view.camera, view.frame_id, trainer.people, degree, trainer.background,
                                        trainer.background_degree)
            rendered = render_frame(view.camera, gaussians, len(trainer.people), trainer.render).rgb.clamp(0, 1)
            union = torch.as_tensor(read_mask(inputs.masks_dir / "union" / f"{frame_name(view.frame_id)}.png"),
                                    device=rendered.device)
            target = view.target()
            entry = {"psnr_db": round(float(psnr(rendered, target)), 3)}
            if union.any():
                entry["psnr_people_db"] = round(float(psnr(rendered, target, union)), 3)
            frames_doc[frame_name(view.frame_id)] = entry
            picture = (rendered.cpu().numpy() * 255.0 + 0.5).astype(np.uint8)
            yield np.concatenate([view.image.cpu().numpy(), picture], axis=1)

    if config.render_video:
        write_mp4(out / "renders" / "joint.mp4", renders(), inputs.fps)
    else:
        for _ in renders():
            pass
    return frames_doc


def _mean_of(frames_doc: dict, key: str) -> float | None:
    values = [f[key] for f in frames_doc.values() if key in f and np.isfinite(f[key])]
    return round(float(np.mean(values)), 3) if values else None


def _report(training: TrainingLog, config: JointConfig, people: list[PersonGaussians], initial_counts: dict,
            frames_doc: dict, prior: str) -> dict:
    return {"format": REPORT_FORMAT, "prior": prior, "iterations": config.total_iterations,
            "resumed_from_iteration": training.resumed_from, "iterations_per_s": round(training.iterations_per_s, 3),
            "training_s": round(training.seconds, 2), "phase_seconds": training.phase_seconds,
            "people": {p.pid: {"gaussians_initial": initial_counts[p.pid], "gaussians": len(p.model),
                               "frames": len(p.body.frame_ids),
                               "pose_offset_mean_deg": round(math.degrees(p.pose_offsets.detach().abs().mean().item()),
                                                             4)} for p in people},
            "psnr_db": _mean_of(frames_doc, "psnr_db"), "psnr_people_db": _mean_of(frames_doc, "psnr_people_db"),
            "frames": frames_doc, "densify_events": training.densify_events, "loss_history": training.losses}
