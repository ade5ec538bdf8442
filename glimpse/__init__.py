"""Glimpse: dynamic 3D scenes of people and places from one video, as Gaussians."""

import os

__version__ = "0.1.0"

# OpenMP reads how its idle threads wait once, when torch (or one of Glimpse's kernels) loads it: so here, before
# either. passive: an idle thread sleeps (threads that busy-wait crawl when processes share the cores);
# GOMP_SPINCOUNT: but first it spins briefly (10,000 spins, about 0.1 ms), so the next of PyTorch's many small
# parallel operations finds it awake instead of paying a wake-up each (docs/speed.md: stage 04's iteration 1.8x
# faster on two cores). Where several processes share the cores, spinning costs them: make test's workers set
# GOMP_SPINCOUNT=0, and so should anyone who runs several Glimpse processes on the same cores. The environment's
# own values win.
OPENMP_ENVIRONMENT = {"OMP_WAIT_POLICY": "passive", "GOMP_SPINCOUNT": "10000"}
for _name, _value in OPENMP_ENVIRONMENT.items():
    os.environ.setdefault(_name, _value)

# Large freed blocks stay with the process for the next iteration instead of being faulted in again page by page
# (glimpse/allocator.py); the environment's own allocator settings win.
from glimpse.allocator import keep_freed_memory  # noqa: E402  (after the OpenMP settings, which must come first)

keep_freed_memory()
