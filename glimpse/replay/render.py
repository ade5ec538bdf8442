"""Rendering a finished run along a camera path over a span of time, optionally without some people
or without the background (docs/renders.md)."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from glimpse.background.stage import render_camera
from glimpse.errors import GlimpseError
from glimpse.humans.person import PersonGaussians, joint_transforms
from glimpse.joint.compose import frame_gaussians, render_frame
from glimpse.replay.cameras import Shot
from glimpse.replay.finished import FinishedRun


@dataclass(frozen=True)
class Edits:
    """What to change in the scene: people to leave out, and whether to draw the background."""

    removed: frozenset[str] = frozenset()
    background: bool = True

    def check(self, run: FinishedRun) -> None:
        unknown = sorted(self.removed - {p.pid for p in run.people})
        if unknown:
            known = ", ".join(p.pid for p in run.people) or "nobody"
            raise GlimpseError(f"cannot remove {', '.join(unknown)}: the run's people are {known}")


def pelvis(person: PersonGaussians, frame_id: int) -> np.ndarray:
    """(3,) the person's pelvis in the world at ``frame_id`` (refined pose)."""
    row = person.row_of_frame[int(frame_id)]
    with torch.no_grad():
        transforms = joint_transforms(person.rig, person.pose(frame_id), person.transl[row], person.scale)
    return transforms[0, :3, 3].cpu().double().numpy()


def people_centre(people: Sequence[PersonGaussians], frame_id: int) -> np.ndarray:
    """(3,) the mean pelvis of the people present at ``frame_id``, else of everyone over their frames."""
    present = [pelvis(p, frame_id) for p in people if p.in_frame(frame_id)]
    if present:
        return np.mean(present, axis=0)
    every = [pelvis(p, f) for p in people for f in p.body.frame_ids]
    if not every:
        raise GlimpseError("the run has no person: an orbit has no centre")
    return np.mean(every, axis=0)


def pair_shots_and_times(shots: Sequence[Shot], times: Sequence[int]) -> list[tuple[Shot, int]]:
    """One (shot, frame id) per video frame: a single shot holds still over the times, a single time is frozen
    along the shots, otherwise both advance together and must have the same length."""
    if not shots or not times:
        raise GlimpseError("nothing to render: no camera or no time")
    if len(shots) == 1:
        return [(shots[0], t) for t in times]
    if len(times) == 1:
        return [(shot, times[0]) for shot in shots]
    if len(shots) != len(times):
        raise GlimpseError(f"{len(shots)} cameras and {len(times)} times: give one of them once, or as many "
                           f"of each")
    return list(zip(shots, times))


@torch.no_grad()
def render_shot(run: FinishedRun, shot: Shot, frame_id: int, edits: Edits, device: torch.device) -> np.ndarray:
    """[H, W, 3] uint8: the scene at ``frame_id`` from ``shot`` (black where nothing is drawn)."""
    camera = render_camera(shot.camera, shot.width, shot.height, device)
    people = [p for p in run.people if p.pid not in edits.removed]
    background = run.background if edits.background else None
    gaussians = frame_gaussians(camera, frame_id, people, run.render.sh_degree, background, run.render.sh_degree)
    rgb = render_frame(camera, gaussians, len(people), run.render, torch.zeros(3, device=device)).rgb
    return (rgb.clamp(0.0, 1.0).cpu().numpy() * 255.0 + 0.5).astype(np.uint8)


def render_video(run: FinishedRun, frames: Sequence[tuple[Shot, int]], edits: Edits, device: torch.device
                 ) -> Iterator[np.ndarray]:
    """The frames of a video, one render per (shot, frame id)."""
    edits.check(run)
    for shot, frame_id in frames:
        yield render_shot(run, shot, frame_id, edits, device)
