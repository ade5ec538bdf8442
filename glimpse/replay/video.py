"""``glimpse render``: a finished run's video (or PNG frames) for a camera path, times and edits."""

from __future__ import annotations

import shutil
from pathlib import Path

import torch
from tqdm import tqdm

from glimpse.io.images import write_png
from glimpse.io.video import write_mp4
from glimpse.replay.finished import load_finished_run
from glimpse.replay.render import Edits, pair_shots_and_times, render_video
from glimpse.replay.request import camera_shots, parse_times

CPU = torch.device("cpu")


def render_command(run_dir: Path, camera: str, time: str, remove: str, background: bool, scene: Path | None,
                   orbit_frames: int, fps: float, out: Path) -> Path:
    """Render and write ``out`` (an .mp4, else a folder of numbered PNGs, written beside it and renamed)."""
    run = load_finished_run(run_dir)
    times = parse_times(time, run)
    frames = pair_shots_and_times(camera_shots(camera, run, times, orbit_frames, scene), times)
    edits = Edits(frozenset(pid for pid in remove.split(",") if pid), background)
    images = tqdm(render_video(run, frames, edits, CPU), total=len(frames), desc="render", unit="frame")
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
