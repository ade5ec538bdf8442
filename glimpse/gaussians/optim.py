"""3DGS's optimiser: Adam with one group per Gaussian parameter, each with its own learning
rate, and an exponentially decaying learning rate for positions."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from glimpse.gaussians.model import GaussianModel

ADAM_EPS = 1e-15  # 3DGS's Adam epsilon (gradients of tiny Gaussians are tiny)


@dataclass(frozen=True)
class LearningRates:
    """Per-parameter Adam learning rates (pipeline.yaml documents units and paper values).

    position_init / position_final: per unit of scene extent, decayed log-linearly over
    ``position_decay_steps`` iterations (already multiplied by the stage's schedule_scale).
    """

    position_init: float
    position_final: float
    position_decay_steps: int
    sh_dc: float
    sh_rest: float
    opacity: float
    scale: float
    rotation: float

    def for_parameter(self, name: str, extent: float) -> float:
        """The starting learning rate of one of :data:`~glimpse.gaussians.model.PARAMETER_NAMES`."""
        return {"means": self.position_init * extent, "sh_dc": self.sh_dc, "sh_rest": self.sh_rest,
                "opacity_logits": self.opacity, "log_scales": self.scale, "quats": self.rotation}[name]


def exponential_lr(step: int, lr_init: float, lr_final: float, steps: int) -> float:
    """Log-linear interpolation from ``lr_init`` (step 0) to ``lr_final`` (step >= ``steps``)."""
    t = min(max(step / max(steps, 1), 0.0), 1.0)
    return math.exp((1.0 - t) * math.log(lr_init) + t * math.log(lr_final))


def make_optimizer(model: GaussianModel, rates: LearningRates, extent: float) -> torch.optim.Adam:
    """Adam over the model's parameters, one named group each; PyTorch's fused implementation (one kernel per
    group instead of a dozen elementwise ones per parameter: about 5x faster on the CPU, same update rule)."""
    groups = [{"params": [param], "lr": rates.for_parameter(name, extent), "name": name}
              for name, param in model.parameter_dict().items()]
    return torch.optim.Adam(groups, lr=0.0, eps=ADAM_EPS, fused=True)


def set_position_lr(optimizer: torch.optim.Optimizer, rates: LearningRates, extent: float, step: int) -> float:
    """Set the means' learning rate for ``step``; returns it."""
    lr = exponential_lr(step, rates.position_init * extent, rates.position_final * extent, rates.position_decay_steps)
    for group in optimizer.param_groups:
        if group["name"] == "means":
            group["lr"] = lr
    return lr
