"""The ingest's parameters (defaults and comments: pipeline.yaml, section ingest)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

from glimpse.errors import GlimpseError


# ingest parameters that leave the scene it writes as it is (glimpse.ingest.stage.scene_parameters)
SCENE_UNCHANGED_BY = ("preview", "checkpoint_frames", "threads")

@dataclass(frozen=True)
class IngestConfig:
    blazepose_dir: str
    max_side: int
    track_max_side: int
    max_frames: int
    start_s: float
    end_s: float | None
    fps: float | None
    threads: int | Literal["auto"]  # after load_ingest_config always a number (auto: compute.threads, resolved)
    detector: Literal["blazepose", "onnx"]
    detector_onnx_path: str | None
    detector_onnx_kind: Literal["rtmdet", "yolox"]
    detector_onnx_min_score: float
    pose: Literal["blazepose", "onnx"]
    pose_onnx_path: str | None
    pose_onnx_box_padding: float
    detect_min_score: float
    detect_nms_iou: float
    detect_tiles: int
    detect_tile_overlap: float
    landmark_min_presence: float
    landmark_refine_heatmap: bool
    landmark_flip_average: bool
    landmark_refine_steps: int
    track_same_person: float
    track_shared_points: int
    track_shared_point_distance: float
    track_covered_iou: float
    track_new_max_overlap: float
    track_behind_max_overlap: float
    track_part_scale: float
    track_max_missing_frames: int
    track_reid_max_distance: float
    track_follow_max_distance: float
    track_reclaim_margin: float
    track_drop_lookalikes: bool
    track_backfill_frames: int
    track_backfill_keypoints_max_overlap: float
    track_look_back_misses: int
    track_min_frames: int
    track_min_height: float
    track_max_upside_down: float
    track_switch_distance: float
    foreground_threshold: int
    foreground_min_area: float
    foreground_region_grow: float
    foreground_close: float
    foreground_person_aspect: float
    foreground_rounds: int
    foreground_min_differing: float
    paint_still_with: Literal["surroundings", "beside"]
    gap_masks: bool
    gap_mask_max_frames: int
    gap_mask_box_grow: float
    gap_mask_min_share: float
    gap_mask_max_share: float
    gap_mask_plate_margin: float
    gap_mask_take_ratio: float
    gap_mask_colour_bins: int
    gap_mask_colour_smoothing: float
    plate_frames: int
    motion_threshold: float
    motion_sample_frames: int
    motion_min_tracked_fraction: float
    mask_threshold: float
    mask_snap_radius: float
    mask_snap_eps: float
    mask_body_radius: float
    mask_depth_cue: Literal["feet", "bones"]
    mask_depth_frames: int
    keypoint_min_confidence: float
    keypoint_smoothing_frames: int
    keypoint_crop_shifts: list[float]
    keypoint_rename_ratio: float
    keypoints_paint_others: bool
    keypoints_paint_still_with: Literal["surroundings", "beside"]
    fit_size_sigma: float
    fit_keypoint_noise_m: float
    fit_unseen_limbs_at_rest: bool
    fit_up_from_torsos: bool
    sides_consistent: bool
    sides_keep_weight: float
    legs_consistent: bool
    legs_keep_weight: float
    legs_dispute_share: float
    legs_planted_window_s: float
    legs_planted_discount: float
    border_squeeze_max: float
    border_squeeze_margin: float
    border_squeeze_window_s: float
    hide_joints_on_others: bool
    keypoints_behind_again: bool
    keypoints_behind_min_cover: float
    keypoints_behind_max_frames: int
    keypoints_behind_after_frames: int
    appearance_bins: int
    appearance_update: float
    appearance_update_max_overlap: float
    preview: bool
    checkpoint_frames: int


def load_ingest_config(cli_params: str = "") -> IngestConfig:
    """pipeline.yaml's ``ingest`` section with "ingest.key=value ..." overrides (the PARAMS syntax); ``threads:
    auto`` resolved to compute.threads' number."""
    from glimpse.compute import ComputeConfig, resolved_threads
    from glimpse.config import command_params, config_from_mapping

    params = command_params(cli_params)
    config = config_from_mapping(IngestConfig, params["ingest"], "pipeline.yaml ingest")
    if config.threads == "auto" or config.threads == 0:
        compute = config_from_mapping(ComputeConfig, params["compute"], "pipeline.yaml compute")
        config = replace(config, threads=resolved_threads(compute))
    elif config.threads < 0:
        raise GlimpseError(f"pipeline.yaml ingest: threads must be auto or a number of threads, found {config.threads}")
    return config
