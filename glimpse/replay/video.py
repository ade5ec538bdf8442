"""``glimpse render``: a finished run's video (or PNG frames) for a camera path, times and edits
(people removed, people driven by a new motion)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import torch

from glimpse.body.motion import BodySequence
from glimpse.errors import GlimpseError
from glimpse.io.images import write_png
from glimpse.io.progress import progress
from glimpse.io.video import write_mp4
from glimpse.replay.finished import load_finished_run
from glimpse.replay.motion import motion_from_spec, retarget
from glimpse.replay.render import Edits, pair_shots_and_times, render_video
from glimpse.replay.request import camera_shots, parse_times

CPU = torch.device("cpu")


def load_motions(specs: list[str], fps: float, builtin_seconds: float) -> dict[str, BodySequence]:
    """``pid=FILE`` (AMASS-style or smplx-style .npz, resampled to ``fps``) or ``pid=builtin:NAME`` (that many
    seconds of a built-in motion) -> pid -> motion."""
    motions = {}
    for spec in specs:
        pid, sep, source = spec.partition("=")
        if not sep or not pid or not source:
            raise GlimpseError(f"--motion {spec!r}: give PID=FILE.npz or PID=builtin:NAME")
        motions[pid] = motion_from_spec(source, fps, builtin_seconds)
    return motions


def render_command(run_dir: Path, camera: str, time: str, remove: str, background: bool, scene: Path | None,
                   orbit_frames: int, fps: float, out: Path, motion_specs: list[str] | None = None,
                   builtin_seconds: float = 4.0) -> Path:
    """Render and write ``out`` (an .mp4, else a folder of numbered PNGs, written beside it and renamed)."""
    run = load_finished_run(run_dir)
    times = parse_times(time, run)
    frames = pair_shots_and_times(camera_shots(camera, run, times, orbit_frames, scene), times)
    motions = load_motions(motion_specs or [], fps, builtin_seconds)
    if motions and len(times) == 1 and len(frames) == 1:  # a frozen scene: the video lasts the longest motion
        frames = frames * max(len(m) for m in motions.values())
    people = {p.pid: p for p in run.people}
    missing = sorted(set(motions) - set(people))
    if missing:
        raise GlimpseError(f"--motion {', '.join(missing)}: the run's people are {', '.join(people) or 'nobody'}")
    driven = {pid: retarget(motion, people[pid].body, times[0], run.body_model, np.arange(len(frames)))
              for pid, motion in motions.items()}
    edits = Edits(frozenset(pid for pid in remove.split(",") if pid), background, driven)
    images = progress(render_video(run, frames, edits, CPU), total=len(frames), desc="render", unit="frame")
    out.parent.mkdir(parents=True, exist_ok=True)
    if out.suffix == ".mp4":
        write_mp4(out, images, fps)
        return out
    tmp = out.with_name(out.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    for k, image in enumerate(images):
        write_png(tmp / f"{k:06d}.png", image)
    shutil.rmtree(out, ignore_errors=True)
    tmp.rename(out)
    return out
