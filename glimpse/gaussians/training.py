"""What every Gaussian training loop shares (background and people): the schedule scale, the scene
extent that sets learning rates and densification thresholds, the order views are visited in and the
colour behind each training render. Everything random is a function of (seed, step)."""

from __future__ import annotations

from typing import Literal

import numpy as np
import torch
from torch import Tensor

from glimpse.render import Camera

FIXED_COLOURS = {"black": (0.0, 0.0, 0.0), "white": (1.0, 1.0, 1.0)}
SEED_STRIDE = 1_000_003  # the random stream of iteration i of a run seeded s starts from s * stride + i
CAMERA_SPREAD_MARGIN = 1.1  # 3DGS's cameras_extent: this times the largest camera distance from their mean

BackgroundColour = Literal["random", "black", "white"]


def scaled_iteration(iteration: int, factor: float) -> int:
    """An absolute iteration of the paper's schedule in a run shortened by ``factor`` (at least 1)."""
    return max(1, int(round(iteration * factor)))


def scene_extent(cameras: list[Camera], points: Tensor) -> float:
    """3DGS's ``cameras_extent`` (1.1 x the largest distance of a camera centre from their mean), or,
    when the cameras barely move (a static camera), the median distance of the initial points [N, 3] from the
    cameras' mean centre, whichever is larger (world units)."""
    centres = torch.stack([c.centre for c in cameras])
    mean = centres.mean(0)
    spread = CAMERA_SPREAD_MARGIN * float((centres - mean).norm(dim=1).max())
    return max(spread, float((points - mean.to(points)).norm(dim=1).median()))


def training_background(colour: BackgroundColour, seed: int, step: int, device: torch.device) -> Tensor:
    """[3] the colour behind the render of training step ``step``: fixed, or uniform random per step."""
    if colour in FIXED_COLOURS:
        return torch.tensor(FIXED_COLOURS[colour], device=device)
    return torch.as_tensor(np.random.default_rng([seed, step]).random(3), dtype=torch.float32, device=device)


def view_order(seed: int, epoch: int, count: int) -> np.ndarray:
    """[count] a permutation of the training views for ``epoch``."""
    return np.random.default_rng([seed, epoch, 1]).permutation(count)


def view_for_step(seed: int, step: int, count: int) -> int:
    """The index of the view iteration ``step`` (from 1) trains on: every view once per epoch, in
    ``view_order``."""
    epoch, slot = divmod(step - 1, count)
    return int(view_order(seed, epoch, count)[slot])
