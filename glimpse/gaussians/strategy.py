"""Adaptive density control as an object (gsplat's strategies).

A trainer asks its strategy for the statistics to gather (``initialize_state``), hands it each render's
screen-space gradients after the backward pass (``observe``) and lets it change the Gaussians after the optimiser's
step (``adapt``), which returns what it did (an event for the report) or None. The operations themselves (clone,
split, prune, reset opacities, with the optimiser's moments following the Gaussians) are glimpse.gaussians.density's.

- :class:`DefaultStrategy`: 3DGS's schedule (the background): densify every ``every`` iterations in
  (start, stop), reset opacities every ``opacity_reset_every``, prune the too large after the first reset.
- :class:`PeopleStrategy`: GTU's schedule for people, in their canonical frame: densify at listed iterations,
  and prune the transparent, the too large and those that left their region every ``prune_every`` iterations
  once the centres are free to move.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

from glimpse.gaussians.density import (
    DensifyConfig, DensityStats, densify, densify_and_prune, keep_only, reset_opacity, screen_threshold,
)
from glimpse.gaussians.model import GaussianModel

Region = Callable[[Tensor], Tensor]  # means [N, 3] -> [N] bool: inside the region the Gaussians must stay in


class Strategy(ABC):
    """When and how a set of Gaussians is densified and pruned."""

    def initialize_state(self, model: GaussianModel) -> DensityStats:
        """The statistics gathered between changes, for ``model``'s Gaussians."""
        return DensityStats(len(model), model.means.device)

    @abstractmethod
    def observe(self, state: DensityStats, means2d_grad: Tensor, radii: Tensor, width: int, height: int,
                step: int) -> None:
        """After the backward pass of iteration ``step``: one render's pixel gradients [N, 2] and radii [N]."""

    @abstractmethod
    def adapt(self, model: GaussianModel, optimizer: torch.optim.Optimizer, state: DensityStats, step: int,
              height: int, seed: int, region: Region | None = None) -> dict | None:
        """After the optimiser's step of iteration ``step``: change the Gaussians if the schedule says so (``height``
        of the training images, pixels; ``seed`` of any random draw; ``region`` the Gaussians must stay in, where
        the strategy prunes by it). Returns the counts of what changed, or None."""


class DefaultStrategy(Strategy):
    """3DGS's adaptive density control with ``config``'s schedule (iterations already scaled) in a scene of
    ``extent`` (world units)."""

    def __init__(self, config: DensifyConfig, extent: float):
        self.config, self.extent = config, extent

    def observe(self, state: DensityStats, means2d_grad: Tensor, radii: Tensor, width: int, height: int,
                step: int) -> None:
        if step < self.config.stop:
            state.update(means2d_grad, radii, width, height)

    def adapt(self, model: GaussianModel, optimizer: torch.optim.Optimizer, state: DensityStats, step: int,
              height: int, seed: int, region: Region | None = None) -> dict | None:
        config, event = self.config, None
        if config.densifies_at(step):
            generator = torch.Generator(device=model.means.device).manual_seed(seed)
            event = densify_and_prune(model, optimizer, state, config, self.extent, height,
                                      config.prunes_large_at(step), generator)
            state.reset(len(model))
        if config.resets_opacity_at(step):
            reset_opacity(model, optimizer, config.opacity_reset_value)
        return event


@dataclass(frozen=True)
class HumanDensity:
    """pipeline.yaml ``06_joint_opt.density``: lengths in metres of body, iterations of the paper's schedule."""

    densify_at: list[int]
    grad_threshold: float
    reference_height_px: float
    split_scale_m: float
    max_gaussians: int
    prune_every: int
    prune_min_opacity: float
    prune_max_scale_m: float


class PeopleStrategy(Strategy):
    """GTU's densification of a person's canonical Gaussians: ``config``'s iterations scaled by ``scaled``;
    pruning starts after iteration ``free_after`` (when the centres are free to move)."""

    def __init__(self, config: HumanDensity, scaled: Callable[[int], int], free_after: int):
        self.config, self.free_after = config, free_after
        self.densify_steps = frozenset(scaled(step) for step in config.densify_at)
        self.prune_every = scaled(config.prune_every)

    def prunes_at(self, step: int) -> bool:
        return step > self.free_after and step % self.prune_every == 0

    def observe(self, state: DensityStats, means2d_grad: Tensor, radii: Tensor, width: int, height: int,
                step: int) -> None:
        state.update(means2d_grad, radii, width, height)

    def adapt(self, model: GaussianModel, optimizer: torch.optim.Optimizer, state: DensityStats, step: int,
              height: int, seed: int, region: Region | None = None) -> dict | None:
        densify_now, prune_now = step in self.densify_steps, self.prunes_at(step)
        if not (densify_now or prune_now):
            return None
        config, event = self.config, {}
        if densify_now:
            generator = torch.Generator(device=model.means.device).manual_seed(seed)
            counts, _ = densify(model, optimizer, state,
                                screen_threshold(config.grad_threshold, config.reference_height_px, height),
                                config.split_scale_m, config.max_gaussians, generator)
            with torch.no_grad():
                transparent = model.opacities() < config.prune_min_opacity
                keep_only(model, optimizer, ~transparent)
            event.update(counts, pruned=int(transparent.sum()), count=len(model))
            state.reset(len(model))
        if prune_now:
            event["pruned_large_or_transparent"] = self._prune(model, optimizer, state, region)
        event["count"] = len(model)
        return event

    def _prune(self, model: GaussianModel, optimizer: torch.optim.Optimizer, state: DensityStats,
               region: Region | None) -> int:
        """Drop the transparent Gaussians, those larger than prune_max_scale_m and those outside ``region``;
        returns how many."""
        with torch.no_grad():
            drop = model.opacities() < self.config.prune_min_opacity
            drop |= model.scales().max(dim=1).values > self.config.prune_max_scale_m
            if region is not None:
                drop |= ~region(model.means)
            if drop.any():
                keep_only(model, optimizer, ~drop)
                state.keep(~drop)
        return int(drop.sum())
