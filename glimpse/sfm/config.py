"""Stage 01's parameters (defaults and comments: pipeline.yaml, section 01_sfm)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True)
class CamerasConfig:
    mode: Literal["auto", "provided", "static", "sfm"]
    fps: float | None
    max_frames: int | None
    motion_threshold: float
    motion_sample_frames: int
    motion_min_tracked_fraction: float
    static_fov_deg: float
    static_pose_tolerance_m: float
    person_mask_dilate: float
    keypoint_min_confidence: float
    keypoint_box_margin: float
    sift_max_features: int
    sift_max_image_size: int
    sift_peak_threshold: float
    sift_domain_size_pooling: bool
    sequential_overlap: int
    min_num_matches: int
    refine: bool
    refine_rounds: int
    refine_max_error_px: float
    refine_loss_scale_px: float
    focal_min_pairs: int
    focal_fov_range_deg: list[float]
    min_registered_fraction: float
    estimate_focal: bool
    deterministic: bool
