"""Stage 03's parameters (defaults and comments: pipeline.yaml, section 03_masks)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True)
class MasksConfig:
    mode: Literal["auto", "provided", "body", "onnx-sam"]
    dilate_m: float
    refine: Literal["auto", "none", "grabcut", "plate"]
    grabcut_iterations: int
    grabcut_band_m: float
    plate_threshold: float
    plate_band_m: float
    plate_core_m: float
    plate_margin_m: float
    plate_frames: int
    occluder_dilate_m: float
    static_occluders: bool
    static_max_std: float
    static_erode_m: float
    static_reach_m: float
    static_motion_min_m: float
    sam_encoder_path: str | None
    sam_decoder_path: str | None
