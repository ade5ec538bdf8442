"""Stage 07's parameters (defaults and comments: pipeline.yaml, section 07_eval)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True)
class EvalConfig:
    heldout: Literal["auto", "input"]
    input_view_every: int
    lpips_net: Literal["alex", "vgg"]
    mean_colour_every: int
