"""``glimpse render``: a finished run's video (or PNG frames) for a camera path, times and edits
(people removed, people driven by a new motion)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import ExitStack
from pathlib import Path

import numpy as np
import torch

from glimpse.body.motion import BodySequence
from glimpse.errors import GlimpseError
from glimpse.io.exr import RGB_CHANNELS, srgb_to_linear, write_exr
from glimpse.io.images import rgb_to_uint8, write_png
from glimpse.io.progress import progress
from glimpse.io.staging import staged_folder
from glimpse.io.video import write_mp4
from glimpse.replay.finished import load_finished_run
from glimpse.replay.motion import motion_from_spec, retarget
from glimpse.replay.render import Edits, ShotPasses, pair_shots_and_times, render_video_passes
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


PASSES = ("rgb", "alpha", "depth", "mask")
NO_SURFACE_DEPTH = 1e10  # the depth pass where nothing is drawn (Blender's Z pass uses the same for empty pixels)


def parse_passes(text: str) -> tuple[str, ...]:
    """``rgb,alpha,depth,mask`` -> the passes asked for, in PASSES' order; rgb is always rendered."""
    asked = {name.strip() for name in text.split(",") if name.strip()}
    unknown = sorted(asked - set(PASSES))
    if unknown:
        raise GlimpseError(f"--passes {text!r}: unknown {', '.join(unknown)}; the passes are {', '.join(PASSES)}")
    return tuple(name for name in PASSES if name in asked | {"rgb"})


def exr_channels(passes: ShotPasses, asked: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The EXR channels of ``asked`` passes: R, G, B (linear light), A, Z (NO_SURFACE_DEPTH where nothing is
    drawn), and one mask.<pid> per person."""
    channels: dict[str, np.ndarray] = {}
    if "rgb" in asked:
        linear = srgb_to_linear(passes.rgb)
        channels.update({name: linear[..., c] for c, name in enumerate(RGB_CHANNELS)})
    if "alpha" in asked:
        channels["A"] = passes.alpha
    if "depth" in asked:
        channels["Z"] = np.where(passes.alpha > 0, passes.depth, NO_SURFACE_DEPTH)
    if "mask" in asked:
        channels.update({f"mask.{pid}": mask for pid, mask in passes.masks.items()})
    return channels


def exr_folder(out: Path) -> Path:
    """Where the EXR passes of a render written to ``out`` go: beside it, <name without suffix>_exr/."""
    return out.with_name(f"{out.stem if out.suffix else out.name}_exr")


def render_command(run_dir: Path, camera: str, time: str, remove: str, background: bool, scene: Path | None,
                   orbit_frames: int, fps: float, out: Path, motion_specs: list[str] | None = None,
                   builtin_seconds: float = 4.0, passes: str = "rgb") -> Path:
    """Render and write ``out`` (an .mp4, else a folder of numbered PNGs, written beside it and renamed); with
    passes beyond rgb, also one OpenEXR file per frame of them all in exr_folder(out)."""
    asked = parse_passes(passes)
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
    driven = {pid: retarget(motion, people[pid].body, times[0], run.body_models[pid], np.arange(len(frames)))
              for pid, motion in motions.items()}
    edits = Edits(frozenset(pid for pid in remove.split(",") if pid), background, driven)
    rendered = progress(render_video_passes(run, frames, edits, CPU), total=len(frames), desc="render", unit="frame")
    out.parent.mkdir(parents=True, exist_ok=True)
    with ExitStack() as folders:
        if asked != ("rgb",):
            exr = folders.enter_context(staged_folder(exr_folder(out)))
            attributes = {"glimpse_run": str(run_dir), "glimpse_depth_units": _world_units(run_dir),
                          "glimpse_colour": "linear sRGB primaries"}
            rendered = _written_exr(rendered, exr, asked, attributes)
        images = (rgb_to_uint8(p.rgb) for p in rendered)
        if out.suffix == ".mp4":
            write_mp4(out, images, fps)
            return out
        pngs = folders.enter_context(staged_folder(out))
        for k, image in enumerate(images):
            write_png(pngs / f"{k:06d}.png", image)
    return out


def _written_exr(rendered: Iterator[ShotPasses], folder: Path, asked: tuple[str, ...], attributes: dict[str, str]
                 ) -> Iterator[ShotPasses]:
    for k, passes in enumerate(rendered):
        write_exr(folder / f"{k:06d}.exr", exr_channels(passes, asked), attributes)
        yield passes


def _world_units(run_dir: Path) -> str:
    """metres, or sfm (an SfM reconstruction's own scale), as stage 01 reported."""
    report = run_dir / "01_sfm" / "report.json"
    return json.loads(report.read_text()).get("units", "unknown") if report.is_file() else "unknown"
