"""Stage 04's parameters (defaults and comments: pipeline.yaml, section 04_bg_pretrain)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

from glimpse.errors import ConfigError
from glimpse.gaussians.density import DensifyConfig
from glimpse.gaussians.optim import LearningRates
from glimpse.gaussians.training import BackgroundColour, scaled_iteration


@dataclass(frozen=True)
class BackgroundConfig:
    init: Literal["auto", "points", "sphere"]
    sphere_radius_m: float
    sphere_spacing_px: float
    sphere_reg_weight: float
    init_colour_frames: int
    points_knn: int
    initial_opacity: float
    iterations: int
    schedule_scale: float
    human_mask_dilate_px: float
    photometric: Literal["l1", "mse"]
    dssim_weight: float
    background_colour: BackgroundColour
    sh_degree_every: int
    lr: LearningRates
    densify: DensifyConfig
    checkpoint_every: int
    never_seen: Literal["keep", "prune"]
    never_seen_min_weight: float
    render_video: bool

    def __post_init__(self) -> None:
        if self.schedule_scale <= 0 or self.iterations < 1:
            raise ConfigError(f"pipeline.yaml 04_bg_pretrain: need iterations >= 1 and schedule_scale > 0, found "
                             f"{self.iterations} and {self.schedule_scale}")
        if not 0.0 <= self.dssim_weight <= 1.0 or not 0.0 < self.initial_opacity < 1.0:
            raise ConfigError("pipeline.yaml 04_bg_pretrain: dssim_weight must lie in [0, 1] and initial_opacity in (0, 1)")

    @property
    def total_iterations(self) -> int:
        return scaled_iteration(self.iterations, self.schedule_scale)

    @property
    def scaled_sh_degree_every(self) -> int:
        return scaled_iteration(self.sh_degree_every, self.schedule_scale)

    @property
    def scaled_lr(self) -> LearningRates:
        return replace(self.lr, position_decay_steps=scaled_iteration(self.lr.position_decay_steps,
                                                                      self.schedule_scale))

    @property
    def scaled_densify(self) -> DensifyConfig:
        d, f = self.densify, self.schedule_scale
        return replace(d, start=scaled_iteration(d.start, f), stop=scaled_iteration(d.stop, f),
                       every=scaled_iteration(d.every, f),
                       opacity_reset_every=scaled_iteration(d.opacity_reset_every, f))
