"""pipeline.yaml's ``diffusion`` section: where the diffusion weights are and how SDS guides (stages 05-06)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from glimpse.errors import ConfigError
from glimpse.prior.sds.cameras import VIEW_KINDS, ZOOMED, SDSCameraConfig
from glimpse.prior.sds.prompts import PromptConfig
from glimpse.prior.sds.schedule import TimestepConfig

Combine = Literal["separate_steps", "summed"]


@dataclass(frozen=True)
class DiffusionConfig:
    sd_path: str | None
    controlnet_path: str | None
    sd_config_path: str | None
    controlnet_config_path: str | None
    allow_cpu: bool
    half_precision: bool
    start_at: int
    guidance_scale: float
    controlnet_scale: float
    resolution_px: int
    early_resolution_px: int
    early_resolution_steps: int
    recon_scale: float
    hard_surface: float
    combine: Combine
    skeleton_line_px: float
    preview_every: int
    prompt: PromptConfig
    timesteps: TimestepConfig
    cameras: SDSCameraConfig

    def __post_init__(self) -> None:
        where = "pipeline.yaml diffusion"
        if self.resolution_px % 8 or self.early_resolution_px % 8 or min(self.resolution_px,
                                                                          self.early_resolution_px) <= 0:
            raise ConfigError(f"{where}: resolution_px and early_resolution_px must be positive multiples of 8 "
                              "(the VAE's downsampling)")
        for name in ("first", "last", "main_text_first"):
            low, high = getattr(self.timesteps, name)
            if not 0.0 < low <= high < 1.0:
                raise ConfigError(f"{where}.timesteps.{name}: need 0 < low <= high < 1, found {[low, high]}")
        cameras = self.cameras
        for name, table in (("early", cameras.early), ("late", cameras.late)):
            unknown = set(table) - set(VIEW_KINDS)
            if unknown or sum(table.values()) <= 0 or min(table.values(), default=0) < 0:
                raise ConfigError(f"{where}.cameras.{name}: probabilities of the kinds {', '.join(VIEW_KINDS)} "
                                  f"(non-negative, not all zero); found {table}")
        if any(kind not in cameras.zoom_scale for kind in ZOOMED if cameras.late.get(kind, 0) > 0):
            raise ConfigError(f"{where}.cameras.zoom_scale: needs an entry for each zoomed kind ({', '.join(ZOOMED)})")
