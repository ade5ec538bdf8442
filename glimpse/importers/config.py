"""The importers' parameters (defaults and comments: pipeline.yaml, section import)."""

from __future__ import annotations

from dataclasses import dataclass

from glimpse.errors import ConfigError


@dataclass(frozen=True)
class ImportConfig:
    eval_every: int  # imported frames between held-out images

    def __post_init__(self) -> None:
        if self.eval_every < 1:
            raise ConfigError(f"import.eval_every: must be at least 1, found {self.eval_every}")
