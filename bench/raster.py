"""Rasterizer benchmark: forward+backward time and peak extra memory per backend,
side by side, on random scenes (N Gaussians, typical scales, depth 2-8 m, 60-degree
camera); then forward-only frames per second with 15k Gaussians (the paper's Table 5).

Each measurement runs in a fresh subprocess, so its peak memory (VmHWM) minus the
memory held before the first render is the renderer's extra memory. ``--device cuda`` times
gsplat on the GPU instead, in this process (synchronised; peak extra memory is torch.cuda's), on the
same scenes with 1024² added, against Glimpse's C++ kernel on that machine's CPU cores in the same run
(the pure-PyTorch backend runs on CPU tensors only).

    .venv/bin/python bench/raster.py [--quick] [--device cuda]
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

COUNTS = (5_000, 20_000, 50_000)
SIZES = (128, 256, 512)
FOV_DEG = 60.0
DEPTH_RANGE_M = (2.0, 8.0)
SCALE_MEDIAN_M, SCALE_LOG_STD = 0.02, 0.5
FPS_COUNT, FPS_SIZES = 15_000, (512, 1024)
TIME_BUDGET_S = 20.0  # per measurement: repeats stop once this much time is spent (at least 2)
MAX_REPEATS = 15  # the median of up to this many calls (7 before 2026-11-28: single runs spread by 10-20%)
WARM_UP_CALLS = 3  # untimed first calls (the allocator's heap and OpenMP's threads are set up over the first few)
TORCH_MAX_PIXELS_X_GAUSSIANS = 256 * 256 * 50_000  # the pure-PyTorch backend is measured up to this size


def _memory_kb(field: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field):
            return int(line.split()[1])
    return 0


def measure(backend: str, count: int, size: int, backward: bool, device: str = "cpu", threads: int = 2) -> dict:
    """Runs in the subprocess: median seconds per call and peak extra memory (MB)."""
    import glimpse  # noqa: F401  (first: it sets how OpenMP's idle threads wait before torch loads OpenMP, as in a run)
    import torch

    from glimpse.render import Camera, RenderConfig, rasterize
    from glimpse.render.projection import fov_to_focal

    torch.manual_seed(0)
    torch.set_num_threads(threads)
    on_gpu = device == "cuda"
    focal = fov_to_focal(FOV_DEG, size)
    camera = Camera(torch.tensor([[focal, 0, (size - 1) / 2], [0, focal, (size - 1) / 2], [0, 0, 1.0]]),
                    torch.eye(3), torch.zeros(3), size, size)
    depth = torch.empty(count).uniform_(*DEPTH_RANGE_M)
    half = depth * math.tan(math.radians(FOV_DEG) / 2)
    means = torch.stack([(torch.rand(count) * 2 - 1) * half, (torch.rand(count) * 2 - 1) * half, depth], -1)
    params = {
        "means": means, "quats": torch.randn(count, 4),
        "scales": torch.exp(torch.randn(count, 3) * SCALE_LOG_STD + math.log(SCALE_MEDIAN_M)),
        "opacities": torch.rand(count) * 0.8 + 0.1, "colors": torch.rand(count, 3),
    }
    if backward:
        params = {k: v.requires_grad_(True) for k, v in params.items()}
    target = torch.rand(size, size, 3)
    if on_gpu:
        torch.cuda.reset_peak_memory_stats()
        camera = Camera(camera.K.cuda(), camera.R.cuda(), camera.t.cuda(), size, size)
        params = {k: v.detach().cuda().requires_grad_(backward) for k, v in params.items()}
        target = target.cuda()

    def call() -> None:
        out = rasterize(camera, **params, settings=RenderConfig(backend, sh_degree=0, antialiased=False))
        if backward:
            ((out.rgb - target) ** 2).mean().backward()
        if on_gpu:
            torch.cuda.synchronize()

    if backend == "cpu":
        from glimpse.render.composite_cpu import extension

        extension()  # load (or build once) the C++ kernel before measuring memory
    before = torch.cuda.memory_allocated() if on_gpu else _memory_kb("VmRSS") * 1024
    for _ in range(WARM_UP_CALLS):
        call()
    times, spent = [], 0.0
    while len(times) < 2 or (spent < TIME_BUDGET_S and len(times) < MAX_REPEATS):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
        spent += times[-1]
    peak = torch.cuda.max_memory_allocated() if on_gpu else _memory_kb("VmHWM") * 1024
    return {"seconds": statistics.median(times), "extra_mb": (peak - before) / 2**20}


def run(backend: str, count: int, size: int, backward: bool) -> dict:
    code = (f"import json, sys; sys.path.insert(0, {str(ROOT)!r}); from bench.raster import measure; "
            f"print(json.dumps(measure({backend!r}, {count}, {size}, {backward})))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="only 50k Gaussians at 256x256")
    parser.add_argument("--device", default="cpu", choices=("cpu", "cuda"),
                        help="cuda: gsplat against the pure-PyTorch backend on the GPU")
    args = parser.parse_args()
    if args.device == "cuda":
        return main_cuda(args.quick)
    cases = [(50_000, 256)] if args.quick else [(n, s) for n in COUNTS for s in SIZES]
    print(f"forward+backward, 2 threads; median seconds; peak extra memory in MB; torch measured up to "
          f"{TORCH_MAX_PIXELS_X_GAUSSIANS:.1e} pixel-Gaussians\n")
    print("| Gaussians | size | cpu s | cpu MB | torch s | torch MB | cpu speed-up |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for count, size in cases:
        cpu = run("cpu", count, size, True)
        if size * size * count <= TORCH_MAX_PIXELS_X_GAUSSIANS:
            ref = run("torch", count, size, True)
            ref_cols = f"{ref['seconds']:.3f} | {ref['extra_mb']:.0f} | {ref['seconds'] / cpu['seconds']:.1f}x"
        else:
            ref_cols = "- | - | -"
        print(f"| {count:,} | {size}² | {cpu['seconds']:.3f} | {cpu['extra_mb']:.0f} | {ref_cols} |", flush=True)
    print(f"\nforward only, {FPS_COUNT:,} Gaussians (paper Table 5 setting), cpu backend\n")
    print("| size | ms per frame | frames per second |")
    print("|---:|---:|---:|")
    for size in FPS_SIZES:
        result = run("cpu", FPS_COUNT, size, False)
        print(f"| {size}² | {1000 * result['seconds']:.1f} | {1 / result['seconds']:.1f} |", flush=True)


def main_cuda(quick: bool) -> None:
    """The GPU tables: gsplat and the PyTorch backend on CUDA tensors, the same scenes as on the CPU."""
    cases = [(50_000, 256)] if quick else [(n, s) for n in COUNTS for s in (*SIZES, 1024)]
    import os

    import torch

    threads = len(os.sched_getaffinity(0))
    print(f"forward+backward; gsplat on {torch.cuda.get_device_name()} (median ms, synchronised; peak extra GPU "
          f"memory in MB) against the C++ kernel on this machine's {threads} CPU threads (median ms)\n")
    print("| Gaussians | size | gsplat ms | gsplat MB | cpu ms | gsplat speed-up |")
    print("|---:|---:|---:|---:|---:|---:|")
    for count, size in cases:
        fast = measure("gsplat", count, size, True, "cuda")
        ref = measure("cpu", count, size, True, "cpu", threads)
        print(f"| {count:,} | {size}² | {1000 * fast['seconds']:.2f} | {fast['extra_mb']:.0f} | "
              f"{1000 * ref['seconds']:.1f} | {ref['seconds'] / fast['seconds']:.0f}x |", flush=True)
    print(f"\nforward only on CUDA, {FPS_COUNT:,} Gaussians (paper Table 5 setting), gsplat\n")
    print("| size | ms per frame | frames per second |")
    print("|---:|---:|---:|")
    for size in FPS_SIZES:
        result = measure("gsplat", FPS_COUNT, size, False, "cuda")
        print(f"| {size}² | {1000 * result['seconds']:.2f} | {1 / result['seconds']:.0f} |", flush=True)


if __name__ == "__main__":
    main()
