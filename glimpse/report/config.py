"""The report's parameters (defaults and comments: pipeline.yaml, section report)."""

from __future__ import annotations

from dataclasses import dataclass

from glimpse.errors import ConfigError


@dataclass(frozen=True)
class ReportConfig:
    stills: int  # frames shown from each video and of the masks, evenly spread over it
    still_height_px: int  # pixels: stills are scaled to this height (small inputs enlarged, nearest pixel)
    mask_opacity: float  # 0..1: how strongly each person's mask colours the frame
    figure_width_in: float  # inches, each plot's width (height: half of it)
    figure_dpi: int  # dots per inch of the plots' PNGs
    log_lines: int  # warnings and errors quoted from each stage's log.txt, at most

    def __post_init__(self) -> None:
        if self.stills < 1 or self.still_height_px < 8 or not 0.0 <= self.mask_opacity <= 1.0:
            raise ConfigError("pipeline.yaml report: need stills >= 1, still_height_px >= 8 and 0 <= mask_opacity "
                              f"<= 1, found {self.stills}, {self.still_height_px} and {self.mask_opacity}")
        if self.figure_width_in <= 0 or self.figure_dpi < 10 or self.log_lines < 0:
            raise ConfigError("pipeline.yaml report: need figure_width_in > 0, figure_dpi >= 10 and log_lines >= 0, "
                              f"found {self.figure_width_in}, {self.figure_dpi} and {self.log_lines}")
