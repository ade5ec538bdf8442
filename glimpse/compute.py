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
    threads: int  # CPU threads for torch, OpenMP and COLMAP; 0 = every core
    seed: int
    frame_cache: int  # input frames (image and masks) stages 04 and 06 keep decoded, on the compute device
    frame_read_ahead: int  # frames read ahead of the training loop on a background thread (< frame_cache)
    auto_schedule_scale: AutoScheduleScale


def resolved_threads(config: ComputeConfig) -> int:
    """Number of CPU threads to use (``threads: 0`` means all cores)."""
    if config.threads < 0:
        raise ValueError(f"compute.threads must be >= 0, found {config.threads}")
    return config.threads or (os.cpu_count() or 1)


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
