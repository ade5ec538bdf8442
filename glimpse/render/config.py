"""The shared ``render`` section of pipeline.yaml: how every render path rasterizes. It travels whole, from
the stage that reads it down to :func:`glimpse.render.rasterize`, so that training, evaluation, turntables and
timings draw the same image for the same settings."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

Backend = Literal["auto", "cpu", "torch", "gsplat"]


@dataclass(frozen=True)
class RenderConfig:
    backend: Backend  # auto: gsplat for CUDA tensors, else the C++ kernel, else pure PyTorch
    sh_degree: int  # the largest spherical-harmonics degree of Gaussian colours
    antialiased: bool  # Mip-Splatting's opacity compensation of the 0.3-pixel dilation (gsplat's "antialiased")
