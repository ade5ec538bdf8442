"""One rasterizer call for a whole frame: the background's Gaussians and each person's, posed for
that frame, concatenated, with a group index per Gaussian (0 = background, 1 + k = person k) so the
rasterizer returns each person's alpha beside the composite (GTU's ``combined_renderer``)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from glimpse.gaussians.model import GaussianModel
from glimpse.humans.person import PersonGaussians, PosedGaussians
from glimpse.render import Camera, RenderOutput, rasterize
from glimpse.render.config import RenderConfig
from glimpse.render.projection import quat_scale_to_covariance
from glimpse.render.sh import num_sh_coeffs, sh_to_rgb

BACKGROUND_GROUP = 0


@dataclass
class FrameGaussians(PosedGaussians):
    """Rasterizer inputs of one frame (N Gaussians in all: means, covariances, opacities, colours as a posed
    person's) and where each person's rows are."""

    groups: Tensor  # [N] int: 0 background, 1 + k person k (k indexes the full list of people)
    rows: dict[int, slice]  # person index k -> its rows


def frame_gaussians(camera: Camera, frame_id: int, people: Sequence[PersonGaussians], human_sh_degree: int,
                    background: GaussianModel | None = None, background_sh_degree: int = 0) -> FrameGaussians:
    """The Gaussians of ``frame_id``: the background (when given) and every person present in that frame."""
    parts: list[tuple[int, PosedGaussians]] = []  # (group, Gaussians)
    if background is not None:
        degree = min(background_sh_degree, background.sh_degree)
        colours = sh_to_rgb(degree, background.sh()[:, : num_sh_coeffs(degree)], background.means - camera.centre)
        parts.append((BACKGROUND_GROUP, PosedGaussians(background.means, quat_scale_to_covariance(
            background.quats, background.scales()), background.opacities(), colours)))
    for k, person in enumerate(people):
        if person.in_frame(frame_id):
            parts.append((1 + k, person.posed(frame_id, camera.centre, human_sh_degree)))
    rows, start = {}, 0
    for group, part in parts:
        if group != BACKGROUND_GROUP:
            rows[group - 1] = slice(start, start + len(part.means))
        start += len(part.means)
    device = camera.R.device
    if not parts:
        empty = torch.zeros(0, 3, device=device)
        return FrameGaussians(empty, torch.zeros(0, 3, 3, device=device), torch.zeros(0, device=device), empty,
                              torch.zeros(0, dtype=torch.long, device=device), rows)
    groups = torch.cat([torch.full((len(part.means),), group, dtype=torch.long, device=device)
                        for group, part in parts])
    return FrameGaussians(*(torch.cat([getattr(part, name) for _, part in parts])
                            for name in ("means", "covariances", "opacities", "colors")), groups, rows)


def render_frame(camera: Camera, gaussians: FrameGaussians, num_people: int, render: RenderConfig,
                 background_colour: Tensor | None = None) -> RenderOutput:
    """Rasterize ``gaussians``; ``group_alpha[1 + k]`` is person k's alpha."""
    return rasterize(camera, means=gaussians.means, opacities=gaussians.opacities,
                     covariances=gaussians.covariances, colors=gaussians.colors, background=background_colour,
                     groups=gaussians.groups, num_groups=1 + num_people, settings=render)
