"""The shared ``prior`` section of pipeline.yaml: which prior fills what no input view saw."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

PriorKind = Literal["auto", "none", "surface", "sds"]


@dataclass(frozen=True)
class PriorConfig:
    kind: PriorKind
