"""Stage 02's parameters (defaults and comments: pipeline.yaml, section 02_smpl_fit)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True)
class FitConfig:
    mode: Literal["auto", "provided", "keypoints3d", "keypoints2d"]
    keypoint_min_confidence: float
