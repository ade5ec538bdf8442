"""Stage 02's parameters (defaults and comments: pipeline.yaml, section 02_smpl_fit)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from glimpse.body.config import pid_path_entries, repository_path
from glimpse.errors import ConfigError

STATED_HEIGHT_RANGE_M = (0.5, 2.5)  # a person's standing height, metres: outside this a stated one is a typo


@dataclass(frozen=True)
class FitWeights:
    keypoint_noise_m: float
    robust_scale_m: float
    robust_scale_3d_m: float
    pose_prior: float
    joint_limits: float
    shape_prior: float
    size_sigma: float
    accel_sigma_m_s2: float
    speed_sigma_m_s: float
    speed_limit_m_s: float
    speed_limit_sigma_m_s: float
    speed_limit_span_s: float
    turn_rate_sigma_deg_s: float
    relative3d_noise_m: float
    relative3d_robust_m: float
    relative3d_size: Literal["model", "fitted"]

    def __post_init__(self) -> None:
        if not self.speed_limit_m_s >= 0 or (self.speed_limit_m_s > 0 and not self.speed_limit_sigma_m_s > 0):
            raise ConfigError("02_smpl_fit.weights.speed_limit_m_s must be 0 (off) or more (m/s), and "
                              "speed_limit_sigma_m_s above 0 when it is on; found "
                              f"{self.speed_limit_m_s} and {self.speed_limit_sigma_m_s}")
        if not self.speed_limit_span_s >= 0:
            raise ConfigError(f"02_smpl_fit.weights.speed_limit_span_s must be 0 or more (seconds), found "
                              f"{self.speed_limit_span_s}")


@dataclass(frozen=True)
class GroundConfig:
    mode: Literal["auto", "off"]
    moving_camera: Literal["common_floor", "planted_feet"]
    contact_speed_m_s: float
    contact_span_s: float
    contact_height_m: float
    normal_prior_m: float
    torso_normal_prior_m: float
    moving_normal_prior_m: float
    standing_thigh_deg: float
    up_from: Literal["torso_axes", "bodies"]
    torso_axis_sigma_deg: float
    torso_up_sigma_deg: float
    torso_keypoint_noise_px: float
    torso_min_confidence: float
    floor_sigma_m: float
    skate_sigma_m_s: float
    shape_ridge: float
    max_placement_factor: float
    parallax_max_error: float
    parallax_size_error: float
    person_heights_m: list[str]
    statures_on_floor: bool
    stature_adult_sigma: float
    stature_child_m: float
    stature_child_sigma: float
    stature_child_share: float
    iterations: int

    def normal_prior(self, static: bool) -> float:
        """Metres (world units): the spread below which the contacts leave the floor's tilt to the up hint
        (glimpse.fit.ground.floor_normal). A moving camera: ``moving_normal_prior_m``; a static one with the up from
        the torso axes (a measured vertical): ``torso_normal_prior_m``; else (the bodies' mean up) ``normal_prior_m``."""
        if not static:
            return self.moving_normal_prior_m
        return self.torso_normal_prior_m if self.up_from == "torso_axes" else self.normal_prior_m


@dataclass(frozen=True)
class SilhouetteConfig:
    mode: Literal["auto", "off"]
    weight: float
    noise_m: float
    robust_m: float
    clothing_m: float
    rate_hz: float
    surface_points: int
    linked_keypoints: int
    outline_pixels: int
    max_side_px: int

    def __post_init__(self) -> None:
        for name in ("weight", "noise_m", "robust_m", "rate_hz"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"02_smpl_fit.silhouette.{name} must be above 0, found {getattr(self, name)} "
                                  f"(mode: off turns the term off)")
        if not self.clothing_m >= 0:
            raise ConfigError(f"02_smpl_fit.silhouette.clothing_m must be 0 or more (metres), found {self.clothing_m}")
        for name in ("surface_points", "linked_keypoints", "outline_pixels", "max_side_px"):
            if not getattr(self, name) >= 1:
                raise ConfigError(f"02_smpl_fit.silhouette.{name} must be at least 1, found {getattr(self, name)}")


@dataclass(frozen=True)
class FitConfig:
    mode: Literal["auto", "provided", "keypoints3d", "keypoints2d"]
    keypoint_min_confidence: float
    relative3d: bool
    min_keypoints: int
    max_interpolated_gap: int
    fit_scale: Literal["auto", "always", "never"]
    scale_motion_rate_hz: float
    weights: FitWeights
    pose_prior_motions: list[str]
    pose_prior_floor_deg: float
    pose_prior_mixture: bool
    pose_prior_mixture_joints: list[str]
    pose_hypotheses: int
    pose_hypothesis_iterations: int
    pose_hypothesis_joint_speed_m_s: float
    pose_hypothesis_rate_hz: float
    unseen_limbs_at_rest: bool
    global_iterations: int
    full_iterations: int
    pose_prior_anneal: list[float]
    robust_scale_anneal: list[float]
    ground: GroundConfig
    silhouette: SilhouetteConfig
    person_shapes: list[str]
    overlay: bool


def stated_person_heights(g: GroundConfig) -> dict[str, float]:
    """``ground.person_heights_m`` as pid -> standing height in metres; malformed entries (and a negative
    ``contact_span_s``, read in the same step) are errors."""
    heights: dict[str, float] = {}
    low, high = STATED_HEIGHT_RANGE_M
    for entry in g.person_heights_m:
        pid, sep, text = str(entry).partition("=")
        pid = pid.strip()
        try:
            metres = float(text) if sep and pid else float("nan")
        except ValueError:
            metres = float("nan")
        if not low <= metres <= high:
            raise ConfigError(f"02_smpl_fit.ground.person_heights_m: {entry!r} is not PID=METRES with a standing "
                              f"height from {low} to {high} m (e.g. p0=1.75)")
        if pid in heights:
            raise ConfigError(f"02_smpl_fit.ground.person_heights_m: person {pid!r} is given twice")
        heights[pid] = metres
    if not g.contact_span_s >= 0:
        raise ConfigError(f"02_smpl_fit.ground.contact_span_s must be 0 or more (seconds), found {g.contact_span_s}")
    return heights


def stated_person_shapes(config: FitConfig) -> dict[str, Path]:
    """``person_shapes`` as pid -> the .npz file of that person's body shape (absolute, or relative to the
    repository, as every path parameter); malformed entries are errors (the files are read by the stage, which
    knows the body model)."""
    entries = pid_path_entries(config.person_shapes, "02_smpl_fit.person_shapes",
                               "p0=runs/clip/02_smpl_fit/humans/p0/body.npz, an .npz with the person's betas")
    return {pid: repository_path(path) for pid, path in entries.items()}
