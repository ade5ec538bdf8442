"""Where a training loop's time goes: wall-clock seconds per named phase of its iterations.

    phases = PhaseTimer(device)
    with phases("render"):
        out = rasterize(...)
    phases.seconds()  # {"render": 12.3, ...}

The trainers mark their phases (data, pose, render, loss, backward, optimiser, prior, densify); the time of
an iteration outside every phase is counted as ``other`` (Python between the phases, learning-rate updates). On
CUDA each phase ends with a synchronisation, so that a phase is charged for its own kernels (the loop reads
the loss every iteration anyway, so this costs little). Stages 04 and 06 write the result in their report
(``phase_seconds``); bench/phase_profile.py prints it as a table.
"""

from __future__ import annotations

import time
from collections import defaultdict
from contextlib import contextmanager
from typing import Iterator

import torch

OTHER = "other"  # time of an iteration outside every marked phase


class PhaseTimer:
    """Accumulates seconds per phase, and per iteration the time outside them (:meth:`iteration`)."""

    def __init__(self, device: torch.device | None = None):
        self._sync = torch.cuda.synchronize if device is not None and device.type == "cuda" else None
        self._seconds: dict[str, float] = defaultdict(float)
        self._in_phases = 0.0  # seconds in phases during the current iteration

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        started = time.perf_counter()
        try:
            yield
        finally:
            if self._sync is not None:
                self._sync()
            spent = time.perf_counter() - started
            self._seconds[name] += spent
            self._in_phases += spent

    @contextmanager
    def iteration(self) -> Iterator[None]:
        """Wraps one whole iteration: what its phases did not cover goes to ``other``."""
        self._in_phases = 0.0
        started = time.perf_counter()
        try:
            yield
        finally:
            self._seconds[OTHER] += max(time.perf_counter() - started - self._in_phases, 0.0)

    def seconds(self) -> dict[str, float]:
        """{phase: seconds}, in the order the phases first ran, ``other`` last."""
        phases = {name: s for name, s in self._seconds.items() if name != OTHER}
        return {**phases, OTHER: self._seconds.get(OTHER, 0.0)}
