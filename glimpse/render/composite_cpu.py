"""The C++ kernels (csrc/: tile binning and compositing, projection, posing a frozen person): built on
first use, cached.

The build cache is keyed by the source, the flags and torch's version, under
$GLIMPSE_CACHE (default ~/.cache/glimpse). Flags are portable (-O3 -mavx2 -mfma, plus
three that allow vectorised selects, see COMMON_FLAGS;
never -march=native, so a shared cache never holds code another CPU cannot run);
a CPU without AVX2/FMA, or a compiler that refuses those flags, gets a plain -O3
build.
"""

from __future__ import annotations

import hashlib
import logging
import os
from functools import lru_cache
from pathlib import Path
from types import ModuleType

import torch
from torch import Tensor

from glimpse.errors import GlimpseError
from glimpse.render.binning import TileBins

log = logging.getLogger("glimpse")
CSRC = Path(__file__).resolve().parent / "csrc"
SOURCES = [CSRC / name for name in ("composite_cpu.cpp", "project_cpu.cpp", "pose_cpu.cpp")]
# -fno-trapping-math -fno-signed-zeros -ffinite-math-only let GCC turn the per-pixel selects
# and min/max into vector blends; unlike -ffast-math they never reassociate arithmetic, so
# finite inputs give IEEE results (the kernel's inputs are finite by construction).
COMMON_FLAGS = ["-O3", "-fno-math-errno", "-fno-trapping-math", "-fno-signed-zeros", "-ffinite-math-only",
                "-fopenmp", "-std=c++17"]
SIMD_FLAGS = ["-mavx2", "-mfma"]


def _cpu_has_simd() -> bool:
    try:
        flags = Path("/proc/cpuinfo").read_text()
    except OSError:
        return False
    return " avx2" in flags and " fma" in flags


def _build(flags: list[str]) -> ModuleType:
    from torch.utils.cpp_extension import load

    digest = hashlib.sha256(" ".join(flags).encode() + torch.__version__.encode())
    for source in SOURCES:
        digest.update(source.read_bytes())
    key = digest.hexdigest()[:12]
    name = f"glimpse_composite_cpu_{key}"
    root = Path(os.environ.get("GLIMPSE_CACHE", Path.home() / ".cache" / "glimpse")) / "extensions" / name
    root.mkdir(parents=True, exist_ok=True)
    if not (root / f"{name}.so").exists():
        log.info("building the C++ rasterizer (%s), once: about a minute", " ".join(flags))
    return load(name=name, sources=[str(s) for s in SOURCES], extra_cflags=flags, extra_ldflags=["-fopenmp"],
                build_directory=str(root), verbose=False)


@lru_cache(maxsize=1)
def extension() -> ModuleType:
    """The compiled kernel; GlimpseError when no build works (use the `torch` backend)."""
    attempts = [COMMON_FLAGS + SIMD_FLAGS, COMMON_FLAGS] if _cpu_has_simd() else [COMMON_FLAGS]
    errors = []
    for flags in attempts:
        try:
            return _build(flags)
        except Exception as exc:  # a compiler error, a missing compiler: try the next flags
            errors.append(f"{' '.join(flags)}: {str(exc).strip().splitlines()[-1] if str(exc).strip() else exc!r}")
    raise GlimpseError("cannot build the C++ rasterizer (render.backend=cpu): " + "; ".join(errors)
                       + ". Install a C++ compiler (Debian: g++) or set render.backend=torch")


def available() -> bool:
    try:
        extension()
    except GlimpseError:
        return False
    return True


class _Composite(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d: Tensor, conics: Tensor, opacities: Tensor, features: Tensor, extents: Tensor,
                bins: TileBins, width: int, height: int) -> Tensor:
        tensors = [t.detach().float().contiguous() for t in (means2d, conics, opacities, features, extents)]
        image, final_T, last = extension().forward(*tensors, bins.tile_offsets, bins.gaussian_ids, width, height,
                                                   bins.tile_size)
        ctx.save_for_backward(*tensors, final_T, last)
        ctx.bins, ctx.size = bins, (width, height)
        return image

    @staticmethod
    def backward(ctx, grad_image: Tensor):
        means2d, conics, opacities, features, extents, final_T, last = ctx.saved_tensors
        width, height = ctx.size
        grads = extension().backward(means2d, conics, opacities, features, extents, ctx.bins.tile_offsets,
                                     ctx.bins.gaussian_ids, final_T, last, grad_image.float(), width, height,
                                     ctx.bins.tile_size)
        return (*grads, None, None, None, None)


def composite_cpu(means2d: Tensor, conics: Tensor, opacities: Tensor, features: Tensor, extents: Tensor,
                  bins: TileBins, width: int, height: int) -> Tensor:
    """features [N, C] composited front to back per pixel -> image [H, W, C] (float32, no background)."""
    return _Composite.apply(means2d, conics, opacities, features, extents, bins, width, height)
