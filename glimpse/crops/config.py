"""Stage 05's parameters (defaults and comments: pipeline.yaml, section 05_textual_inversion)."""

from __future__ import annotations

from dataclasses import dataclass

from glimpse.errors import ConfigError
from glimpse.prior.sds.train_identity import IdentityConfig


@dataclass(frozen=True)
class CropsConfig:
    crop_size_px: int
    crop_margin: float
    min_mask_px: int
    max_crops: int
    mask_erode_px: float
    mask_feather_px: float
    skeleton_line_px: float
    front_max_deg: float
    back_min_deg: float
    prompt_template: str
    identity: IdentityConfig  # prior.kind sds only: the CustomDiffusion training

    def __post_init__(self) -> None:
        if self.crop_size_px < 16 or self.crop_margin < 1.0:
            raise ConfigError("pipeline.yaml 05_textual_inversion: need crop_size_px >= 16 and crop_margin >= 1, "
                              f"found {self.crop_size_px} and {self.crop_margin}")
        if not 0.0 <= self.front_max_deg < self.back_min_deg <= 180.0:
            raise ConfigError("pipeline.yaml 05_textual_inversion: need 0 <= front_max_deg < back_min_deg <= 180, "
                              f"found {self.front_max_deg} and {self.back_min_deg}")
        if "{view}" not in self.prompt_template:
            raise ConfigError("pipeline.yaml 05_textual_inversion.prompt_template must contain {view}, found "
                              f"{self.prompt_template!r}")
