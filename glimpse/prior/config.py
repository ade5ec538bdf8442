"""The prior sections of pipeline.yaml: ``prior`` (which prior fills what no input view saw; shared
by stages 05-07) and ``prior_surface`` (the surface prior's weights and schedule; stage 06)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from glimpse.cameras.orbit import OrbitConfig
from glimpse.errors import ConfigError

PriorKind = Literal["auto", "none", "surface", "sds"]


@dataclass(frozen=True)
class PriorConfig:
    kind: PriorKind


@dataclass(frozen=True)
class SurfacePriorConfig:
    min_seen_frames: int
    start_at: int
    refresh_every: int
    mirror_weight: float
    part_anchor: float
    part_min_seen: float
    garments: bool
    skin_colour_distance: float
    skin_reach_m: float
    neutral_garment: list[float]
    colour_confidence: float
    colour_max_angle_deg: float
    grazing_colour: bool
    colour: float
    view_dependent: float
    seen_colour: float
    surface: float
    surface_margin_m: float
    needle: float
    needle_ratio: float
    silhouette_fill: float
    silhouette_trim: float
    silhouette_margin_m: float
    views_per_person: int
    orbit: OrbitConfig

    def __post_init__(self) -> None:
        if self.min_seen_frames < 1 or self.refresh_every < 1 or self.views_per_person < 1:
            raise ConfigError("pipeline.yaml prior_surface: min_seen_frames, refresh_every and views_per_person "
                              "must be at least 1")
        if (self.needle_ratio < 1.0 or self.surface_margin_m <= 0 or self.silhouette_margin_m < 0
                or self.colour_confidence <= 0):
            raise ConfigError("pipeline.yaml prior_surface: need needle_ratio >= 1, surface_margin_m > 0, "
                              "silhouette_margin_m >= 0 and colour_confidence > 0")
        if (len(self.neutral_garment) != 3 or not all(0.0 <= c <= 1.0 for c in self.neutral_garment)
                or self.skin_colour_distance <= 0 or self.skin_reach_m < 0):
            raise ConfigError("pipeline.yaml prior_surface: need neutral_garment as three values in 0..1, "
                              "skin_colour_distance > 0 and skin_reach_m >= 0")
        low, high = self.orbit.elevation_deg
        if not -90.0 <= low <= high <= 90.0 or self.orbit.radius_m <= 0 or not 0 < self.orbit.fovy_deg < 180:
            raise ConfigError("pipeline.yaml prior_surface.orbit: need -90 <= elevation_deg[0] <= elevation_deg[1] "
                              "<= 90, radius_m > 0 and 0 < fovy_deg < 180")
