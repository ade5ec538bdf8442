"""Render speed of a finished run: stage 07's speed.json and `make bench` (paper Table 5; docs/renders.md).

Novel pose: each person alone, driven by a new motion in their own body frame (metres, y up), seen by a
camera that circles their pelvis once over the timed frames, ``radius_m`` away with a ``fovy_deg`` field
of view (2.6 m and 49.1 degrees: the body fills about 70% of the image height, as in ZJU-Mocap's views),
at each square size. One frame is posing (skin weights, blended transforms, covariances A Σ Aᵀ,
view-dependent colours) plus rasterizing. Whole scene: input views at the input resolution, every person
present posed plus the background, as stage 07's videos draw them.

Times are medians over the timed frames, after untimed warm-up frames. Memory is the peak above what the
process held before the first (warm-up) frame: the renderer's working memory, resident on CPU (Linux,
/proc/self), allocated on CUDA; the Gaussians themselves are held before and counted apart (model_mb).
"""

from __future__ import annotations

import ctypes
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from glimpse.body.motion import BodySequence
from glimpse.body.params import BodyParams
from glimpse.cameras.model import render_camera
from glimpse.cameras.orbit import turn_cameras
from glimpse.eval.config import SpeedConfig
from glimpse.humans.compose import frame_gaussians, render_frame
from glimpse.humans.person import PersonGaussians
from glimpse.io.images import rgb_to_uint8
from glimpse.render import RenderConfig, rasterize
from glimpse.render.rasterize import choose_backend
from glimpse.replay.finished import FinishedRun
from glimpse.replay.motion import motion_from_spec, upright

SPEED_FORMAT = "glimpse-speed/1"
MB = 2.0**20
PROTOCOL = ("novel pose: each person alone on white, driven by {motion}, a camera circling the pelvis once "
            "({radius_m} m away, {fovy_deg} degree field of view, square images); whole scene: {scene_frames} input "
            "views at the input resolution, people and background. One frame = posing + colours + rasterizing; "
            "median over {frames} timed frames after {warmup} warm-up frames; memory: peak above the level "
            "before the first frame (resident on CPU, allocated on CUDA)")


@dataclass(frozen=True)
class SpeedTiming:
    """One timed render setting: Gaussians drawn per frame, image size (pixels), median milliseconds per
    frame and its two parts, peak extra memory (MB; None where it cannot be read)."""

    gaussians: int
    width: int
    height: int
    frames: int
    ms_per_frame: float
    posing_ms: float
    raster_ms: float
    peak_extra_mb: float | None

    @property
    def fps(self) -> float:
        return 1000.0 / self.ms_per_frame

    def as_dict(self) -> dict:
        return {**asdict(self), "fps": round(self.fps, 2)}


class PeakMemory:
    """``with PeakMemory(device) as peak: ...`` then ``peak.extra_mb``: the peak above the level at entry."""

    def __init__(self, device: torch.device):
        self.device = device
        self.extra_mb: float | None = None

    def __enter__(self) -> PeakMemory:
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)
            torch.cuda.reset_peak_memory_stats(self.device)
            self._start = torch.cuda.memory_allocated(self.device)
        else:
            self._start = _resident_kb("VmRSS") if _reset_resident_peak() else None
        return self

    def __exit__(self, *exc) -> None:
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)
            self.extra_mb = (torch.cuda.max_memory_allocated(self.device) - self._start) / MB
        elif self._start is not None:
            self.extra_mb = max(_resident_kb("VmHWM") - self._start, 0) * 1024 / MB


def _resident_kb(field: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field):
            return int(line.split()[1])
    raise OSError(f"/proc/self/status has no {field}")


def _reset_resident_peak() -> bool:
    """Hand freed heap memory back to the system (glibc), so that reusing it counts again, and reset the
    process's peak resident memory (Linux >= 4.0); False where that is not possible."""
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass
    try:
        Path("/proc/self/clear_refs").write_text("5")
        _resident_kb("VmHWM")
        return True
    except OSError:
        return False


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def time_frames(frame_count: int, warmup: int, pose: Callable[[int], object], draw: Callable[[int, object], int],
                device: torch.device, width: int, height: int) -> SpeedTiming:
    """Time ``pose(k)`` then ``draw(k, posed) -> Gaussians drawn`` for k in range(warmup + frame_count)."""
    posing, raster, counts = [], [], []
    with torch.no_grad(), PeakMemory(device) as peak:
        for k in range(warmup):
            draw(k, pose(k))
        for k in range(warmup, warmup + frame_count):
            _sync(device)
            start = time.perf_counter()
            posed = pose(k)
            _sync(device)
            middle = time.perf_counter()
            counts.append(draw(k, posed))
            _sync(device)
            posing.append(middle - start)
            raster.append(time.perf_counter() - middle)
    totals = [a + b for a, b in zip(posing, raster)]
    return SpeedTiming(int(round(statistics.mean(counts))), width, height, frame_count,
                       1000.0 * statistics.median(totals), 1000.0 * statistics.median(posing),
                       1000.0 * statistics.median(raster), peak.extra_mb)


def driven_in_body_frame(person: PersonGaussians, motion: BodySequence) -> PersonGaussians:
    """The person's Gaussians driven by ``motion`` in their own body frame (y up, metres, scale 1), frame
    ids 0..T-1, frozen for rendering (PersonGaussians.freeze)."""
    rest_pelvis = person.rig.rest_joints[0].double().cpu().numpy()
    orient, transl = upright(motion, rest_pelvis)
    body = BodyParams(np.arange(len(motion)), person.body.betas, orient, motion.body_pose, transl, 1.0,
                      person.body.body_model, np.zeros(len(motion), bool))
    driven = PersonGaussians(person.pid, person.model, person.grid, person.rig, body)
    return driven.to(person.pose_offsets.device).freeze()


def time_novel_pose(person: PersonGaussians, motion: BodySequence, size: int, config: SpeedConfig,
                    render: RenderConfig, device: torch.device) -> SpeedTiming:
    """Frames per second of ``person`` driven by ``motion`` at ``size``² pixels (see the module docstring)."""
    driven = driven_in_body_frame(person, motion)
    pelvis = driven.rig.rest_joints[0].cpu().double().numpy() + driven.transl.cpu().double().numpy()  # [T, 3]
    total = config.warmup_frames + config.frames
    white = torch.ones(3, device=device)
    cameras = [render_camera(pinhole, device) for pinhole in
               turn_cameras(pelvis[np.arange(total) % len(motion)], config.radius_m, config.fovy_deg, size)]

    def pose(k: int):
        return driven.posed(k % len(motion), cameras[k].centre, render.sh_degree)

    def draw(k: int, posed) -> int:
        rasterize(cameras[k], means=posed.means, covariances=posed.covariances, opacities=posed.opacities,
                  colors=posed.colors, background=white, settings=render)
        return len(posed.means)

    return time_frames(config.frames, config.warmup_frames, pose, draw, device, size, size)


def time_scene(run: FinishedRun, frame_ids: Sequence[int], warmup: int, device: torch.device) -> SpeedTiming:
    """Frames per second of the whole scene of ``run`` from its input cameras at ``frame_ids`` (cycled through
    for the warm-up frames first), drawn as render_shot draws it, in two timed parts."""
    degree = run.render.sh_degree
    black = torch.zeros(3, device=device)
    ids = list(frame_ids)
    cameras = {fid: render_camera(run.cameras[fid], device) for fid in ids}

    def frame(k: int) -> int:
        return ids[(k - warmup) % len(ids)]

    def pose(k: int):
        fid = frame(k)
        return frame_gaussians(cameras[fid], fid, run.people, degree, run.background, degree)

    def draw(k: int, gaussians) -> int:
        rgb_to_uint8(render_frame(cameras[frame(k)], gaussians, len(run.people), run.render, black).rgb)
        return len(gaussians.means)

    return time_frames(len(ids), warmup, pose, draw, device, run.width, run.height)


def evenly_spread(values: Sequence[int], count: int) -> list[int]:
    """``count`` entries of ``values`` evenly spread from first to last (all of them when there are fewer)."""
    if len(values) <= count:
        return list(values)
    return [values[int(i)] for i in np.linspace(0, len(values) - 1, count).round()]


def speed_report(run: FinishedRun, config: SpeedConfig, device: torch.device,
                 progress: Callable[[str], None] = lambda line: None) -> dict:
    """speed.json of ``run``: every person at every size, and the whole scene (SPEED_FORMAT)."""
    backend = choose_backend(run.render.backend, device)
    motion = motion_from_spec(config.motion, config.motion_fps, config.frames / config.motion_fps)
    people = {}
    for person in run.people:
        timings = {}
        for size in config.sizes_px:
            timings[str(size)] = time_novel_pose(person, motion, size, config, run.render, device).as_dict()
            progress(f"speed: {person.pid} at {size}px: {timings[str(size)]['fps']:.1f} fps")
        people[person.pid] = {"gaussians": len(person.model), "model_mb": round(model_megabytes(person), 3),
                              "novel_pose": timings}
    scene_frames = evenly_spread(sorted(run.cameras), config.scene_frames)
    scene = time_scene(run, scene_frames, config.warmup_frames, device)
    progress(f"speed: whole scene at {run.width}x{run.height}: {scene.fps:.1f} fps")
    threads = torch.get_num_threads() if device.type == "cpu" else None
    return {"format": SPEED_FORMAT, "backend": backend, "device": device_name(device), "threads": threads,
            "people": people, "scene": scene.as_dict(),
            "protocol": PROTOCOL.format(motion=config.motion, radius_m=config.radius_m, fovy_deg=config.fovy_deg,
                                        scene_frames=len(scene_frames),
                                        frames=config.frames, warmup=config.warmup_frames)}


def model_megabytes(person: PersonGaussians) -> float:
    """Megabytes of a person's Gaussians and skinning grid."""
    tensors = [*person.model.parameters(), person.grid.weights]
    return sum(t.numel() * t.element_size() for t in tensors) / MB


def device_name(device: torch.device) -> str:
    if device.type == "cuda":
        return torch.cuda.get_device_name(device)
    import platform

    return platform.processor() or platform.machine()


def speed_markdown(report: dict) -> str:
    """The report as Markdown tables (speed.md)."""
    lines = [f"# Render speed ({report['backend']} backend, {report['device']}"
             + (f", {report['threads']} threads" if report["threads"] else "") + ")", "",
             "| person | Gaussians | size | ms per frame | fps | posing ms | raster ms | peak extra MB |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for pid, entry in report["people"].items():
        for size, t in entry["novel_pose"].items():
            lines.append(_row(pid, t))
    lines += ["", "| whole scene | Gaussians | size | ms per frame | fps | posing ms | raster ms | peak extra MB |",
              "|---|---:|---:|---:|---:|---:|---:|---:|", _row("input views", report["scene"]), "",
              f"Protocol: {report['protocol']}.", ""]
    return "\n".join(lines)


def _row(name: str, t: dict) -> str:
    memory = "-" if t["peak_extra_mb"] is None else f"{t['peak_extra_mb']:.0f}"
    return (f"| {name} | {t['gaussians']:,} | {t['width']}x{t['height']} | {t['ms_per_frame']:.1f} | {t['fps']:.1f} | "
            f"{t['posing_ms']:.1f} | {t['raster_ms']:.1f} | {memory} |")
