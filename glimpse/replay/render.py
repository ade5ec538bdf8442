"""Rendering a finished run along a camera path over a span of time, optionally without some people,
without the background, or with people driven by a new motion (docs/renders.md)."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from glimpse.body.params import BodyParams
from glimpse.cameras.model import PinholeCamera, render_camera
from glimpse.errors import GlimpseError
from glimpse.humans.compose import BACKGROUND_GROUP, FrameGaussians, frame_gaussians, render_frame
from glimpse.humans.person import PersonGaussians
from glimpse.io.images import rgb_to_uint8
from glimpse.replay.finished import FinishedRun


@dataclass(frozen=True)
class Edits:
    """What to change in the scene: people to leave out, whether to draw the background, and people driven
    by a new motion (pid -> body parameters whose frame ids are the video's frame indices, replay.motion)."""

    removed: frozenset[str] = frozenset()
    background: bool = True
    driven: dict[str, BodyParams] = field(default_factory=dict)

    def check(self, run: FinishedRun) -> None:
        unknown = sorted(self.removed - {p.pid for p in run.people})
        if unknown:
            known = ", ".join(p.pid for p in run.people) or "nobody"
            raise GlimpseError(f"cannot remove {', '.join(unknown)}: the run's people are {known}")
        unknown = sorted(set(self.driven) - {p.pid for p in run.people})
        if unknown:
            raise GlimpseError(f"cannot drive {', '.join(unknown)}: the run's people are "
                               f"{', '.join(p.pid for p in run.people) or 'nobody'}")


def pelvis(person: PersonGaussians, frame_id: int) -> np.ndarray:
    """(3,) the person's pelvis in the world at ``frame_id`` (refined pose)."""
    with torch.no_grad():
        transforms = person.frame_transforms(frame_id)
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


def pair_shots_and_times(shots: Sequence[PinholeCamera], times: Sequence[int]) -> list[tuple[PinholeCamera, int]]:
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


def driven_people(run: FinishedRun, edits: Edits) -> list[PersonGaussians]:
    """The people of ``edits.driven``: their Gaussians and skinning, posed by the new body parameters."""
    return [PersonGaussians(p.pid, p.model, p.grid, p.rig, edits.driven[p.pid]).to(p.pose_offsets.device).freeze()
            for p in run.people if p.pid in edits.driven and p.pid not in edits.removed]


def _joined(first: FrameGaussians, second: FrameGaussians, first_people: int) -> FrameGaussians:
    """Both sets of Gaussians in one; the second's people numbered after the first's ``first_people``."""
    offset = len(first.means)
    rows = dict(first.rows)
    rows.update({first_people + k: slice(r.start + offset, r.stop + offset) for k, r in second.rows.items()})
    groups = torch.where(second.groups > BACKGROUND_GROUP, second.groups + first_people, second.groups)
    return FrameGaussians(*(torch.cat([getattr(first, name), getattr(second, name)])
                            for name in ("means", "covariances", "opacities", "colors")),
                          torch.cat([first.groups, groups]), rows)


@dataclass(frozen=True)
class ShotPasses:
    """One render's passes. rgb [H, W, 3] in [0, 1] (sRGB-encoded, as the input frames; black where nothing is
    drawn); alpha [H, W]; depth [H, W]: the expected camera z of what is drawn, in the world's units, 0 where
    nothing is; masks: pid -> [H, W] that person's share of the alpha (what of them is visible: people and
    background in front are accounted for; with the background's share, the shares sum to the alpha)."""

    rgb: np.ndarray
    alpha: np.ndarray
    depth: np.ndarray
    masks: dict[str, np.ndarray]


@torch.no_grad()
def render_shot_passes(run: FinishedRun, shot: PinholeCamera, frame_id: int, edits: Edits, device: torch.device,
                       video_index: int = 0, driven: Sequence[PersonGaussians] = ()) -> ShotPasses:
    """The scene at ``frame_id`` from ``shot``, the ``driven`` people (driven_people) at their motion's
    ``video_index``: every pass of the render."""
    camera = render_camera(shot, device)
    people = [p for p in run.people if p.pid not in edits.removed and p.pid not in edits.driven]
    background = run.background if edits.background else None
    degree = run.render.sh_degree
    gaussians = frame_gaussians(camera, frame_id, people, degree, background, degree)
    if driven:
        gaussians = _joined(gaussians, frame_gaussians(camera, video_index, driven, degree), len(people))
    out = render_frame(camera, gaussians, len(people) + len(driven), run.render, torch.zeros(3, device=device))
    pids = [p.pid for p in people] + [p.pid for p in driven]
    masks = {pid: out.group_alpha[1 + k].cpu().numpy() for k, pid in enumerate(pids)} if pids else {}
    return ShotPasses(out.rgb.clamp(0.0, 1.0).cpu().numpy(), out.alpha.cpu().numpy(), out.depth.cpu().numpy(), masks)


def render_shot(run: FinishedRun, shot: PinholeCamera, frame_id: int, edits: Edits, device: torch.device,
                video_index: int = 0, driven: Sequence[PersonGaussians] = ()) -> np.ndarray:
    """[H, W, 3] uint8: the colour pass of render_shot_passes."""
    return rgb_to_uint8(render_shot_passes(run, shot, frame_id, edits, device, video_index, driven).rgb)


def render_video_passes(run: FinishedRun, frames: Sequence[tuple[PinholeCamera, int]], edits: Edits,
                        device: torch.device) -> Iterator[ShotPasses]:
    """Every pass of a video's frames, one render per (shot, frame id); driven people follow the video's index."""
    edits.check(run)
    driven = driven_people(run, edits)
    for index, (shot, frame_id) in enumerate(frames):
        yield render_shot_passes(run, shot, frame_id, edits, device, index, driven)


def render_video(run: FinishedRun, frames: Sequence[tuple[PinholeCamera, int]], edits: Edits, device: torch.device
                 ) -> Iterator[np.ndarray]:
    """The frames of a video as [H, W, 3] uint8 (render_video_passes' colour)."""
    for passes in render_video_passes(run, frames, edits, device):
        yield rgb_to_uint8(passes.rgb)
