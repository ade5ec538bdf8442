"""Stage 07's standard set of videos of a finished run (docs/renders.md, CONTRACTS.md 07_eval):

  input.mp4                 the input view re-rendered, beside the input frame
  heldout_<camera>.mp4      each held-out camera's render beside its ground truth
  orbit.mp4                 the camera turning once around the people while the video plays
  freeze.mp4                time frozen at the chosen frame, the camera turning around (a turntable)
  person_<pid>.mp4          each person alone in canonical pose, turning (elevation 0)
  removed_<pid>.mp4         the input view without the chosen person (left); the same with the background no
                            input frame showed tinted (right, stage 04's never_seen/ masks)
  motion_<pid>.mp4          the chosen person driven by a new motion from the chosen frame, scene frozen
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch

from glimpse.cameras.model import render_camera
from glimpse.cameras.orbit import box_centre, turn_cameras
from glimpse.errors import GlimpseError
from glimpse.eval.config import RenderSetConfig
from glimpse.eval.views import ScoredView
from glimpse.humans.person import PersonGaussians
from glimpse.io.images import frame_files, frame_name, read_mask, read_rgb, rgb_to_uint8
from glimpse.io.video import write_mp4
from glimpse.render import RenderConfig, rasterize
from glimpse.replay.cameras import mean_up, orbit_path
from glimpse.replay.finished import FinishedRun
from glimpse.replay.motion import motion_from_spec, retarget
from glimpse.replay.render import Edits, people_centre, render_shot, render_video

log = logging.getLogger(__name__)

NEVER_SEEN_TINT = (255, 0, 255)  # magenta: the background no input frame showed, in removed_<pid>.mp4
NEVER_SEEN_TINT_WEIGHT = 0.5


def chosen_time(config: RenderSetConfig, run: FinishedRun) -> int:
    frames = sorted(run.cameras)
    if config.time == "middle":
        return frames[len(frames) // 2]
    if config.time not in run.cameras:
        raise GlimpseError(f"07_eval.renders.time: frame {config.time} is not an input frame with a camera "
                           f"(frames {frames[0]}..{frames[-1]})")
    return int(config.time)


def side_by_side(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Two [H, W, 3] uint8 images next to each other (the right one padded or cropped to the left's height)."""
    height = left.shape[0]
    right = right[:height]
    right = np.pad(right, ((0, height - right.shape[0]), (0, 0), (0, 0)))
    return np.concatenate([left, right], axis=1)


@torch.no_grad()
def canonical_turntable(person: PersonGaussians, frames: int, size: int, radius_m: float,
                        fovy_deg: float, render: RenderConfig, device: torch.device) -> Iterator[np.ndarray]:
    """[size, size, 3] uint8 renders of the person alone in canonical pose from ``frames`` azimuths evenly
    spread over a turn (0 = the front), elevation 0, ``radius_m`` from the body's centre, on white."""
    points = person.rig.canonical_vertices.cpu().numpy()
    centre = box_centre(points)
    for pinhole in turn_cameras(np.tile(centre, (frames, 1)), radius_m, fovy_deg, size):
        rgb = rasterize(render_camera(pinhole, device), **person.model.render_inputs(render.sh_degree),
                        background=torch.ones(3, device=device), settings=render).rgb
        yield rgb_to_uint8(rgb)


def with_never_seen(image: np.ndarray, never_seen_dir: Path, frame_id: int) -> np.ndarray:
    """[H, W, 3] uint8 ``image`` with the pixels of stage 04's never-seen mask of ``frame_id`` tinted (unchanged
    where the frame has no mask)."""
    path = never_seen_dir / f"{frame_name(frame_id)}.png"
    if not path.is_file():
        return image
    mask = read_mask(path)[..., None]
    tinted = (1.0 - NEVER_SEEN_TINT_WEIGHT) * image + NEVER_SEEN_TINT_WEIGHT * np.array(NEVER_SEEN_TINT)
    return np.where(mask, tinted + 0.5, image).astype(np.uint8)


def write_render_set(run: FinishedRun, config: RenderSetConfig, heldout: list[ScoredView], frames_dir: Path,
                     never_seen_dir: Path, fps: float, out: Path, device: torch.device) -> dict[str, str]:
    """Write every video of the set under ``out``; returns file name -> what it shows. ``never_seen_dir``: stage
    04's never_seen/ masks (the removal video tints those pixels)."""
    written: dict[str, str] = {}

    def wrote(name: str, what: str) -> None:
        written[name] = what
        log.info("07_eval: wrote renders/%s (%s)", name, what)

    times = sorted(run.cameras)[:: max(config.every, 1)]
    frozen = chosen_time(config, run)
    step_fps = fps / max(config.every, 1)

    frames = frame_files(frames_dir)
    inputs = [t for t in times if t in frames]
    if inputs:
        write_mp4(out / "input.mp4", (side_by_side(render_shot(run, run.cameras[t], t, Edits(), device), read_rgb(frames[t]))
                                      for t in inputs), step_fps)
        wrote("input.mp4", "input view: render (left), input frame (right)")
    by_camera: dict[str, list[ScoredView]] = {}
    for view in heldout:
        by_camera.setdefault(view.name.split("/")[0], []).append(view)
    for camera, views in sorted(by_camera.items()):
        write_mp4(out / f"heldout_{camera}.mp4", (side_by_side(
            render_shot(run, v.camera, v.frame_id, Edits(), device), read_rgb(v.image))
            for v in views), step_fps)
        wrote(f"heldout_{camera}.mp4", f"held-out camera {camera}: render (left), ground truth (right)")
    if not run.people:
        return written
    axis, start = mean_up(list(run.cameras.values())), run.cameras[frozen]
    centre = people_centre(run.people, frozen)
    orbit = orbit_path(start, centre, axis, len(times))
    write_mp4(out / "orbit.mp4", render_video(run, list(zip(orbit, times)), Edits(), device), step_fps)
    wrote("orbit.mp4", "one turn around the people while the video plays")
    freeze = orbit_path(start, centre, axis, config.orbit_frames)
    write_mp4(out / "freeze.mp4", render_video(run, [(s, frozen) for s in freeze], Edits(), device), fps)
    wrote("freeze.mp4", f"time frozen at frame {frozen}, one turn around the people")
    for person in run.people:
        write_mp4(out / f"person_{person.pid}.mp4", canonical_turntable(
            person, config.turntable_frames, config.turntable_size_px,
            config.turntable_radius_m, config.turntable_fovy_deg, run.render, device), fps)
        wrote(f"person_{person.pid}.mp4", f"{person.pid} alone, canonical pose, one turn")
    chosen = run.people[0].pid if config.person == "first" else config.person
    if chosen not in {p.pid for p in run.people}:
        raise GlimpseError(f"07_eval.renders.person: no person {chosen!r} in the run (people: "
                           f"{', '.join(p.pid for p in run.people)})")
    edits = Edits(frozenset({chosen}))
    removed = (render_shot(run, run.cameras[t], t, edits, device) for t in times)
    write_mp4(out / f"removed_{chosen}.mp4", (side_by_side(image, with_never_seen(image, never_seen_dir, t))
                                              for image, t in zip(removed, times)), step_fps)
    wrote(f"removed_{chosen}.mp4", f"input view without {chosen} (left); the same with the background no input "
                                   f"frame showed tinted magenta (right)")
    person = next(p for p in run.people if p.pid == chosen)
    if person.in_frame(frozen):
        motion = motion_from_spec(config.motion, fps, config.motion_seconds)
        driven = retarget(motion, person.body, frozen, run.body_models[person.pid], np.arange(len(motion)))
        write_mp4(out / f"motion_{chosen}.mp4", render_video(run, [(run.cameras[frozen], frozen)] * len(motion),
                                                             Edits(driven={chosen: driven}), device), fps)
        wrote(f"motion_{chosen}.mp4", f"{chosen} driven by {config.motion} from frame {frozen}, scene frozen")
    return written
