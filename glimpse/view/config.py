"""The viewer's parameters (defaults and comments: pipeline.yaml, section view)."""

from __future__ import annotations

from dataclasses import dataclass

from glimpse.errors import ConfigError


@dataclass(frozen=True)
class ViewConfig:
    host: str  # address the viewer listens on (127.0.0.1: this machine only)
    port: int  # TCP port of the viewer's page
    preview_max_side_px: int  # pixels: the longer side of the live render while the camera moves
    still_max_side_px: int  # pixels: the longer side of the render once the camera rests, and of screenshots
    sharp_after_s: float  # seconds the camera must rest before the sharp render replaces the live one
    jpeg_quality: int  # 1..100: quality of the frames sent to the browser
    play_fps: float  # frames per second when playing (input frames, or motion frames)
    motion_seconds: float  # seconds of a built-in motion
    motion_fps: float  # frames per second the motion is sampled at

    def __post_init__(self) -> None:
        if not 0 <= self.port <= 65535 or not 16 <= self.preview_max_side_px <= self.still_max_side_px:
            raise ConfigError("pipeline.yaml view: need 0 <= port <= 65535 and 16 <= preview_max_side_px <= "
                              f"still_max_side_px, found {self.port}, {self.preview_max_side_px} and "
                              f"{self.still_max_side_px}")
        if not 1 <= self.jpeg_quality <= 100 or min(self.play_fps, self.motion_seconds, self.motion_fps) <= 0:
            raise ConfigError("pipeline.yaml view: need 1 <= jpeg_quality <= 100 and play_fps, motion_seconds, "
                              f"motion_fps > 0, found {self.jpeg_quality}, {self.play_fps}, {self.motion_seconds} "
                              f"and {self.motion_fps}")
        if self.sharp_after_s < 0:
            raise ConfigError(f"pipeline.yaml view: sharp_after_s must be >= 0 seconds, found {self.sharp_after_s}")
