"""Differentiable Gaussian splatting: `rasterize(camera, means=..., ..., settings=...)` over three backends
(cpu: C++ kernel; torch: pure-PyTorch reference; gsplat: CUDA). See rasterize.py."""

from glimpse.render.config import RenderConfig
from glimpse.render.projection import Camera
from glimpse.render.rasterize import RenderOutput, rasterize

__all__ = ["Camera", "RenderConfig", "RenderOutput", "rasterize"]
