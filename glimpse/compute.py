"""The shared ``compute`` section: device, threads, seed."""

from __future__ import annotations

import os
import random
from dataclasses import dataclass
from typing import Literal

import numpy as np


@dataclass(frozen=True)
class AutoScheduleScale:
    """What a section's ``schedule_scale: auto`` becomes on each device (glimpse.config.resolve_auto_schedules)."""

    cpu: float
    cuda: float


@dataclass(frozen=True)
class ComputeConfig:
    device: Literal["auto", "cpu", "cuda"]
    threads: int | Literal["auto"]  # CPU threads for torch, OpenMP and COLMAP; auto (or 0): usable_cores()
    seed: int
    frame_cache: int  # input frames (image and masks) stages 04 and 06 keep decoded, on the compute device
    frame_read_ahead: int  # frames read ahead of the training loop on a background thread (< frame_cache)
    lpips_target_cache_mb: float  # stage 06's LPIPS target features kept with the cached frames, MB in all
    auto_schedule_scale: AutoScheduleScale


def usable_cores() -> int:
    """The CPU cores this process may run on: its affinity, which is what Slurm, a container or taskset grants
    (os.cpu_count() counts the whole machine's)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # no affinity on this platform (macOS)
        return os.cpu_count() or 1


def resolved_threads(config: ComputeConfig) -> int:
    """Number of CPU threads to use: ``threads``, or with ``auto`` (or 0) every core this process may use, on
    the CPU and on CUDA alike (there the CPU prepares frames, fits bodies and runs COLMAP)."""
    if config.threads == "auto" or config.threads == 0:
        return usable_cores()
    if config.threads < 0:
        raise ValueError(f"compute.threads must be >= 0 or auto, found {config.threads}")
    return config.threads


def apply_compute(config: ComputeConfig) -> None:
    """Seed every generator and set thread counts; call once at stage start."""
    threads = resolved_threads(config)
    random.seed(config.seed)
    np.random.seed(config.seed)
    try:
        import torch
    except ImportError:  # stages that do not need torch still run
        return
    torch.manual_seed(config.seed)
    torch.set_num_threads(threads)


def resolve_device(config: ComputeConfig):
    """The torch device of ``compute.device``: auto = CUDA when present, else the CPU; asking for
    cuda on a machine without it is an error that says so."""
    import torch

    from glimpse.errors import ConfigError

    if config.device == "cuda" and not torch.cuda.is_available():
        raise ConfigError("compute.device is cuda but torch sees no CUDA device here; use auto or cpu")
    if config.device == "cpu" or not torch.cuda.is_available():
        return torch.device("cpu")
    return torch.device("cuda")
