"""Stage 06's parameters (defaults and comments: pipeline.yaml, section 06_joint_opt)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

from glimpse.errors import ConfigError
from glimpse.gaussians.optim import LearningRates
from glimpse.gaussians.strategy import HumanDensity, PeopleStrategy
from glimpse.gaussians.training import scaled_iteration
from glimpse.humans.visibility import VisibilityConfig


@dataclass(frozen=True)
class JointLossWeights:
    mse: float
    dssim: float
    lpips: float
    lpips_net: Literal["alex", "vgg"]
    hard_surface: float
    lpips_margin_px: int
    lpips_min_px: int


@dataclass(frozen=True)
class JointConfig:
    iterations: int
    schedule_scale: float
    initial_opacity: float
    initial_grey: float
    initial_scale_knn: int
    fix_centres_until: int
    early_min_opacity: float
    sh_degree_every: int
    background_colour: Literal["random", "black", "white"]
    loss: JointLossWeights
    lr: LearningRates
    background_lr: LearningRates
    density: HumanDensity
    visibility: VisibilityConfig
    refine_pose: bool
    pose_lr: float
    checkpoint_every: int
    render_video: bool

    def __post_init__(self) -> None:
        if self.schedule_scale <= 0 or self.iterations < 1:
            raise ConfigError(f"pipeline.yaml 06_joint_opt: need iterations >= 1 and schedule_scale > 0, found "
                              f"{self.iterations} and {self.schedule_scale}")
        if not 0.0 < self.initial_opacity < 1.0 or not 0.0 <= self.early_min_opacity < 1.0:
            raise ConfigError("pipeline.yaml 06_joint_opt: initial_opacity must lie in (0, 1) and "
                              "early_min_opacity in [0, 1)")

    def scaled(self, iteration: int) -> int:
        """An absolute iteration of the paper's schedule in this run (CONTRACTS.md "Iterations")."""
        return scaled_iteration(iteration, self.schedule_scale)

    @property
    def total_iterations(self) -> int:
        return self.scaled(self.iterations)

    def people_strategy(self) -> PeopleStrategy:
        """The people's densification: at the (scaled) densify_at iterations, and pruning every prune_every
        (scaled) iterations once the centres are free to move."""
        return PeopleStrategy(self.density, self.scaled, self.scaled(self.fix_centres_until))

    def centres_fixed_at(self, step: int) -> bool:
        return step <= self.scaled(self.fix_centres_until)

    def human_sh_degree(self, step: int, max_degree: int) -> int:
        return min((step - 1) // self.scaled(self.sh_degree_every), max_degree)

    def scaled_rates(self, rates: LearningRates) -> LearningRates:
        return replace(rates, position_decay_steps=self.scaled(rates.position_decay_steps))
