"""Stage 07's parameters (defaults and comments: pipeline.yaml, section 07_eval)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True)
class RenderSetConfig:
    """The videos of stage 07's renders/ (glimpse.replay.standard)."""

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
class EvalConfig:
    heldout: Literal["auto", "input"]
    input_view_every: int
    lpips_net: Literal["alex", "vgg"]
    mean_colour_every: int
    renders: RenderSetConfig
