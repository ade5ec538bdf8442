"""Stage 07's parameters (defaults and comments: pipeline.yaml, section 07_eval)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from glimpse.errors import ConfigError


@dataclass(frozen=True)
class RenderSetConfig:
    """The videos of stage 07's renders/ (glimpse.eval.renders)."""

    enabled: bool
    every: int  # frames: the videos over time use every this many input frames
    time: Literal["middle"] | int  # the frozen time of freeze.mp4 and motion_<pid>.mp4, the orbit's centre time
    orbit_frames: int
    turntable_frames: int
    turntable_size_px: int
    turntable_radius_m: float
    turntable_fovy_deg: float
    person: str  # "first" or a pid: who is removed and who is driven
    motion: str  # "builtin:NAME" or a .npz path
    motion_seconds: float  # length of a built-in motion


@dataclass(frozen=True)
class SpeedConfig:
    """speed.json: novel-pose and whole-scene render speed (glimpse.eval.speed)."""

    enabled: bool
    sizes_px: list[int]  # square image sides of the novel-pose timings
    frames: int  # timed frames per person and size, and motion frames
    warmup_frames: int
    motion: str  # "builtin:NAME" or a .npz path
    motion_fps: float
    radius_m: float
    fovy_deg: float
    scene_frames: int  # input views timed for the whole scene

    def __post_init__(self) -> None:
        if not self.sizes_px or min(self.sizes_px) < 1 or self.frames < 1 or self.warmup_frames < 0:
            raise ConfigError("pipeline.yaml 07_eval.speed: need at least one size >= 1 pixel, frames >= 1 and "
                              f"warmup_frames >= 0, found {self.sizes_px}, {self.frames} and {self.warmup_frames}")
        if self.scene_frames < 1 or self.motion_fps <= 0 or self.radius_m <= 0 or not 0 < self.fovy_deg < 180:
            raise ConfigError("pipeline.yaml 07_eval.speed: need scene_frames >= 1, motion_fps > 0, radius_m > 0 and "
                              f"0 < fovy_deg < 180, found {self.scene_frames}, {self.motion_fps}, {self.radius_m} "
                              f"and {self.fovy_deg}")


@dataclass(frozen=True)
class EvalConfig:
    heldout: Literal["auto", "input"]
    input_view_every: int
    lpips_net: Literal["alex", "vgg"]
    mean_colour_every: int
    renders: RenderSetConfig
    speed: SpeedConfig
