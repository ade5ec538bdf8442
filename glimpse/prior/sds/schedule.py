"""When and how hard score distillation pushes (paper Sec. 4.4 and supplementary; GTU_REFERENCE.md 4).

Every iteration here counts SDS steps: the joint iteration minus the iteration SDS starts at (paper:
1000), both already under ``schedule_scale``; each person gets one SDS step per joint iteration, so a
person's step count is the same number. The noise level tau is a fraction of the diffusion's
training timesteps (tau = t / T).

Timestep ranges, U[low, high]:
- ``supplementary`` (default): U[0.5, 0.98] for 2k steps, then both bounds move linearly to
  U[0.02, 0.3] over the next 2k, and stay there (HiFA's annealing).
- ``main_text``: U[0.2, 0.98] for 2k steps, then the maximum decays linearly to 0.3 over 2k.
- ``official``: U[0.5, 0.98] for 2k steps; U[0.3, max] with max falling linearly 0.98 -> 0.3 over the
  next 2k; then U[0.02, 0.3].

The reconstruction loss weight follows the current maximum: lambda_recon = recon_scale x tau_max^2
(supplementary: 1e6) from the SDS start on, 1 before.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import torch

TimestepSchedule = Literal["supplementary", "main_text", "official"]


@dataclass(frozen=True)
class TimestepConfig:
    schedule: TimestepSchedule
    hold_steps: int       # SDS steps at the first range (paper: 2000)
    anneal_steps: int     # SDS steps over which it moves to the last range (paper: 2000)
    first: list[float]    # [low, high]: the first range of the supplementary and official schedules (0.5, 0.98)
    last: list[float]     # the range they end at (0.02, 0.3)
    main_text_first: list[float]  # the main text's first range (0.2, 0.98)
    main_text_final_max: float  # the main text's maximum after its decay (0.3)
    official_anneal_min: float  # the official code's minimum while its maximum falls (0.3)


def _lerp(a: float, b: float, fraction: float) -> float:
    return a + (b - a) * fraction


def timestep_range(step: int, config: TimestepConfig) -> tuple[float, float]:
    """(low, high) noise fractions at SDS step ``step`` (0 = the first SDS step), schedule-scaled counts."""
    fraction = min(max((step - config.hold_steps) / max(config.anneal_steps, 1), 0.0), 1.0)
    if config.schedule == "main_text":
        low, high = config.main_text_first
        return low, _lerp(high, config.main_text_final_max, fraction)
    (first_low, first_high), (last_low, last_high) = config.first, config.last
    if config.schedule == "supplementary":
        return _lerp(first_low, last_low, fraction), _lerp(first_high, last_high, fraction)
    if config.schedule == "official":
        if step < config.hold_steps:
            return first_low, first_high
        if step < config.hold_steps + config.anneal_steps:
            return config.official_anneal_min, _lerp(first_high, last_high, fraction)
        return last_low, last_high
    raise ValueError(f"unknown timestep schedule {config.schedule!r}")


def sample_timestep(step: int, config: TimestepConfig, train_timesteps: int, generator: torch.Generator) -> int:
    """An integer diffusion timestep t = tau T with tau ~ U[low, high] at SDS step ``step``, clamped to
    [1, T - 1]."""
    low, high = timestep_range(step, config)
    tau = low + (high - low) * float(torch.rand((), generator=generator))
    return int(min(max(round(tau * train_timesteps), 1), train_timesteps - 1))


def recon_weight(step: int, config: TimestepConfig, recon_scale: float) -> float:
    """lambda_recon at SDS step ``step`` (negative: before SDS starts, 1): recon_scale x tau_max^2."""
    if step < 0:
        return 1.0
    return recon_scale * timestep_range(step, config)[1] ** 2
