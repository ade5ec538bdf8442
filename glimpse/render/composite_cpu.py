"""The C++ kernels (csrc/: tile binning and compositing, projection, covariances and SH colours, posing
people for training and frozen ones for rendering): built when the environment is set up (make venv runs
``python -m glimpse.render.composite_cpu``; about a minute and a half on two cores), else on first use; cached.

The build cache is keyed by the source, the flags, torch's version and its path, under
$GLIMPSE_CACHE (default ~/.cache/glimpse). The sources are copied into it and built from
there, so every checkout that uses one environment shares one build (torch's loader records the
sources' paths and torch's). One process builds at a time, under a lock (glimpse.locks) that a killed
build never leaves behind; a process that waits longer than $GLIMPSE_BUILD_WAIT_S seconds
(default 900) stops with a message naming the builder. Flags are portable (-O3 -mavx2 -mfma, plus
three that allow vectorised selects, see COMMON_FLAGS;
never -march=native, so a shared cache never holds code another CPU cannot run);
a CPU without AVX2/FMA, or a compiler that refuses those flags, gets a plain -O3
build.
"""

from __future__ import annotations

import hashlib
import logging
import os
import shutil
from functools import lru_cache
from pathlib import Path
from types import ModuleType

import torch
from torch import Tensor

from glimpse.errors import GlimpseError
from glimpse.locks import LockBusy, exclusive_lock
from glimpse.render.binning import TileBins

log = logging.getLogger("glimpse")
CSRC = Path(__file__).resolve().parent / "csrc"
SOURCES = [CSRC / name for name in (
    "composite_cpu.cpp", "project_cpu.cpp", "preprocess_cpu.cpp", "pose_cpu.cpp", "skinning_cpu.cpp",
    "ssim_cpu.cpp", "mesh_raster_cpu.cpp")]
HEADERS = [CSRC / "sh_basis.h", CSRC / "polar.h", CSRC / "raster_rules.h", CSRC / "lanes.h"]
# -fno-trapping-math -fno-signed-zeros -ffinite-math-only let GCC turn the per-pixel selects
# and min/max into vector blends; unlike -ffast-math they never reassociate arithmetic, so
# finite inputs give IEEE results (the kernel's inputs are finite by construction).
COMMON_FLAGS = ["-O3", "-fno-math-errno", "-fno-trapping-math", "-fno-signed-zeros", "-ffinite-math-only",
                "-fopenmp", "-std=c++17"]
SIMD_FLAGS = ["-mavx2", "-mfma"]
# Seconds a process waits for another one building the same extension (environment, not a pipeline parameter:
# it changes no result).
BUILD_WAIT_ENV, BUILD_WAIT_DEFAULT_S = "GLIMPSE_BUILD_WAIT_S", 900.0


def _cpu_has_simd() -> bool:
    try:
        flags = Path("/proc/cpuinfo").read_text()
    except OSError:
        return False
    return " avx2" in flags and " fma" in flags


def _build_wait_s() -> float:
    text = os.environ.get(BUILD_WAIT_ENV, "") or str(BUILD_WAIT_DEFAULT_S)
    try:
        return float(text)
    except ValueError:
        raise GlimpseError(f"{BUILD_WAIT_ENV} must be a number of seconds, got {text!r}") from None


def _build(flags: list[str]) -> ModuleType:
    from torch.utils.cpp_extension import load

    # torch's own path is in the build's commands: each environment gets its build (one shared by two checkouts'
    # environments would be rebuilt, a minute each time, whenever the other ran)
    digest = hashlib.sha256(" ".join(flags).encode() + torch.__version__.encode() + torch.__file__.encode())
    for source in SOURCES + HEADERS:
        digest.update(source.read_bytes())
    key = digest.hexdigest()[:12]
    name = f"glimpse_composite_cpu_{key}"
    root = Path(os.environ.get("GLIMPSE_CACHE", Path.home() / ".cache" / "glimpse")) / "extensions" / name
    with exclusive_lock(root.with_name(f"{name}.lock"), "building the C++ rasterizer", _build_wait_s(),
                        hint=f"If it hangs, stop it; or wait longer with {BUILD_WAIT_ENV}=<seconds>."):
        (root / "lock").unlink(missing_ok=True)  # torch's own build marker, left behind by a killed build
        sources = []
        for source in SOURCES + HEADERS:  # one path for every checkout: ninja then sees nothing to rebuild
            copy = root / "src" / source.name
            if not copy.is_file() or copy.read_bytes() != source.read_bytes():
                copy.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(source, copy)
            if source in SOURCES:
                sources.append(str(copy))
        if not (root / f"{name}.so").exists():
            log.info("building the C++ rasterizer (%s), once: about a minute", " ".join(flags))
        return load(name=name, sources=sources, extra_cflags=flags, extra_ldflags=["-fopenmp"],
                    build_directory=str(root), verbose=False)


@lru_cache(maxsize=1)
def extension() -> ModuleType:
    """The compiled kernel; GlimpseError when no build works (use the `torch` backend), LockBusy when another
    process has been building it for too long."""
    attempts = [COMMON_FLAGS + SIMD_FLAGS, COMMON_FLAGS] if _cpu_has_simd() else [COMMON_FLAGS]
    errors = []
    for flags in attempts:
        try:
            return _build(flags)
        except LockBusy:
            raise
        except Exception as exc:  # a compiler error, a missing compiler: try the next flags
            errors.append(f"{' '.join(flags)}: {str(exc).strip().splitlines()[-1] if str(exc).strip() else exc!r}")
    raise GlimpseError("cannot build the C++ rasterizer (render.backend=cpu): " + "; ".join(errors)
                       + ". Install a C++ compiler (Debian: g++) or set render.backend=torch")


@lru_cache(maxsize=1)
def available() -> bool:
    """Whether the kernel builds here (a build that waits too long for another process raises LockBusy); tried
    once per process."""
    try:
        extension()
    except LockBusy:
        raise
    except GlimpseError:
        return False
    return True


def kernel_applies(*tensors: Tensor) -> bool:
    """Whether the C++ kernels can compute on ``tensors``: all float32 on the CPU, and the kernel builds here."""
    return all(t.device.type == "cpu" and t.dtype == torch.float32 for t in tensors) and available()


class _Composite(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d: Tensor, conics: Tensor, opacities: Tensor, features: Tensor, extents: Tensor,
                bins: TileBins, width: int, height: int) -> Tensor:
        tensors = [t.detach().float().contiguous() for t in (means2d, conics, opacities, features, extents)]
        # the records pack each Gaussian's inputs for the kernels; the backward reads the forward's
        image, final_T, last, records = extension().forward(*tensors, bins.tile_offsets, bins.gaussian_ids, width,
                                                            height, bins.tile_size)
        ctx.save_for_backward(*tensors, final_T, last, records)
        ctx.bins, ctx.size = bins, (width, height)
        return image

    @staticmethod
    def backward(ctx, grad_image: Tensor):
        means2d, conics, opacities, features, extents, final_T, last, records = ctx.saved_tensors
        width, height = ctx.size
        grads = extension().backward(means2d, conics, opacities, features, extents, ctx.bins.tile_offsets,
                                     ctx.bins.gaussian_ids, final_T, last, records, grad_image.float(), width, height,
                                     ctx.bins.tile_size)
        return (*grads, None, None, None, None)


def composite_cpu(means2d: Tensor, conics: Tensor, opacities: Tensor, features: Tensor, extents: Tensor,
                  bins: TileBins, width: int, height: int) -> Tensor:
    """features [N, C] composited front to back per pixel -> image [H, W, C] (float32, no background)."""
    return _Composite.apply(means2d, conics, opacities, features, extents, bins, width, height)


if __name__ == "__main__":  # make venv: build the kernels now rather than in the first stage that renders
    print("the C++ kernels:", "built" if available() else "not built (render.backend torch will be used)")
