"""The benchmarks' one timing loop (not a benchmark itself: run_all.py skips files starting with "_")."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable


def no_sync() -> None:
    """For CPU work: nothing is queued to wait for."""


def median_seconds(call: Callable[[], object], repeats: int, warmup: int = 1,
                   sync: Callable[[], None] = no_sync) -> float:
    """Median wall time of ``call()`` over ``repeats`` timed calls, after ``warmup`` untimed ones; ``sync``
    (e.g. torch.cuda.synchronize) runs before and after each call so that queued device work is counted."""
    for _ in range(warmup):
        call()
        sync()
    times = []
    for _ in range(repeats):
        sync()
        start = time.perf_counter()
        call()
        sync()
        times.append(time.perf_counter() - start)
    return statistics.median(times)
