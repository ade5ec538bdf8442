"""The shared ``render`` section of pipeline.yaml."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True)
class RenderConfig:
    backend: Literal["auto", "cpu", "torch", "gsplat"]
    sh_degree: int
    antialiased: bool
