"""Glimpse: dynamic 3D scenes of people and places from one video, as Gaussians."""

import os

__version__ = "0.1.0"

# OpenMP reads how its idle threads wait once, when torch (or one of Glimpse's kernels) loads it: so here, before
# either. passive: an idle thread sleeps (threads that busy-wait crawl when processes share the cores: make test,
# batches); GOMP_SPINCOUNT: but first it spins about 0.1 ms (libgomp counts some 100,000 spins a millisecond), so
# the next of PyTorch's many small parallel operations finds it awake instead of paying a wake-up each
# (docs/speed.md: stage 04's iteration 1.8x faster on two cores). The environment's own values win.
OPENMP_ENVIRONMENT = {"OMP_WAIT_POLICY": "passive", "GOMP_SPINCOUNT": "10000"}
for _name, _value in OPENMP_ENVIRONMENT.items():
    os.environ.setdefault(_name, _value)
