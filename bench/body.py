"""Body model timings: forward pass of the SMPL layer (glimpse.body.model.BodyModel)
on a random 6,890-vertex SMPL-format model, float32, 2 CPU threads, no autograd.

Prints one Markdown table: median wall time over repeats per batch size, throughput
(bodies/s) and the time relative to batch 1 of the same measurement in the same run.
Each measurement is a small function in MEASUREMENTS returning rows, so more rows
(e.g. skin-weight grids) can be added beside the forward pass.
"""

from __future__ import annotations

import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench._timing import median_seconds  # noqa: E402
from glimpse.body.model import BodyModel  # noqa: E402
from tests.body_files import write_random_smpl_npz  # noqa: E402

THREADS = 2
SEED = 0
BATCH_SIZES = (1, 64, 512)
REPEATS = {1: 30, 64: 10, 512: 5}  # timed calls per batch size (after one warm-up call)
POSE_STD_RAD = 0.4


@dataclass(frozen=True)
class Context:
    """What the measurements share: the random model file and the model loaded from it."""

    model_path: Path
    model: BodyModel


@dataclass(frozen=True)
class Row:
    measurement: str
    batch: int
    seconds: float  # median wall time of one call


def random_inputs(batch: int, rng: np.random.Generator) -> dict[str, torch.Tensor]:
    def t(*shape: int, std: float = 1.0) -> torch.Tensor:
        return torch.tensor(rng.normal(scale=std, size=shape), dtype=torch.float32)

    return {
        "betas": t(batch, 10),
        "global_orient": t(batch, 3),
        "body_pose": t(batch, 69, std=POSE_STD_RAD),
        "transl": t(batch, 3),
        "scale": torch.ones(batch),
    }


def measure_forward(ctx: Context) -> list[Row]:
    """BodyModel.forward (vertices, joints, transforms), inference (torch.no_grad)."""
    rng = np.random.default_rng(SEED)
    rows = []
    for batch in BATCH_SIZES:
        inputs = random_inputs(batch, rng)
        with torch.no_grad():
            seconds = median_seconds(lambda inputs=inputs: ctx.model(**inputs), REPEATS[batch])
        rows.append(Row("forward", batch, seconds))
    return rows


MEASUREMENTS: list[Callable[[Context], list[Row]]] = [measure_forward]


def table(rows: list[Row]) -> str:
    first = {}
    for row in rows:
        first.setdefault(row.measurement, row)
    lines = [
        "| measurement | batch | median ms | bodies/s | time vs batch 1 |",
        "|---|---:|---:|---:|---:|",
    ]
    for row in rows:
        base = first[row.measurement]
        ratio = row.seconds / base.seconds if base.batch == 1 else float("nan")
        lines.append(
            f"| {row.measurement} | {row.batch} | {1e3 * row.seconds:.2f} | {row.batch / row.seconds:,.0f} | "
            f"{ratio:.1f}x |"
        )
    return "\n".join(lines)


SKIN_POINTS = 100_000
SKIN_NOISE_M = 0.02  # points scattered around the body surface, metres


def skinning_table() -> str:
    """Skin-weight grid bake and lookup on the free body in the Da-pose, against direct IDW."""
    from glimpse.body.config import BodyConfig, resolve_model_path
    from glimpse.body.skinning import (
        bake_skin_weight_grid, canonical_body_pose, canonical_to_posed, deform_gaussians, idw_skin_weights,
    )
    from glimpse.config import config_from_mapping, load_pipeline_yaml

    config = config_from_mapping(BodyConfig, load_pipeline_yaml()["body"], "pipeline.yaml body")
    skin = config.skinning
    model = BodyModel.from_file(resolve_model_path(config))
    pose = torch.as_tensor(canonical_body_pose(config.canonical_hip_angle_deg), dtype=torch.float32)[None]
    with torch.no_grad():
        canonical = model(torch.zeros(1, 10), torch.zeros(1, 3), pose)
        posed = model(torch.zeros(1, 10), torch.zeros(1, 3), torch.zeros(1, 69))
    vertices = canonical.vertices[0].double().numpy()
    rng = np.random.default_rng(SEED)
    points = vertices[rng.integers(0, len(vertices), SKIN_POINTS)] + rng.normal(0, SKIN_NOISE_M, (SKIN_POINTS, 3))
    points_t = torch.as_tensor(points, dtype=torch.float32)
    rows = []
    start = time.perf_counter()
    grid = bake_skin_weight_grid(vertices, model.data.weights, skin.grid_resolution, skin.grid_margin_m,
                                 skin.knn, skin.idw_power)
    rows.append((f"bake grid {skin.grid_resolution}^3, k={skin.knn}", time.perf_counter() - start))
    direct = median_seconds(lambda: idw_skin_weights(points, vertices, model.data.weights, skin.knn, skin.idw_power), 3)
    rows.append((f"direct IDW, {SKIN_POINTS:,} points (baseline)", direct))
    lookup = median_seconds(lambda: grid.lookup(points_t), 10)
    rows.append((f"grid lookup, {SKIN_POINTS:,} points", lookup))
    weights = grid.lookup(points_t)
    covariances = torch.eye(3).expand(SKIN_POINTS, 3, 3) * 1e-4

    def deform():
        blended = canonical_to_posed(weights, posed.transforms[0], canonical.transforms[0])
        return deform_gaussians(points_t, covariances, blended)

    rows.append((f"deform {SKIN_POINTS:,} Gaussians (means, covariances)", median_seconds(deform, 10)))
    lines = [f"free body ({model.num_vertices} vertices), {THREADS} threads\n",
             "| operation | median ms | vs direct IDW |", "|---|---:|---:|"]
    lines += [f"| {name} | {1e3 * sec:.1f} | {direct / sec:.1f}x |" for name, sec in rows]
    return "\n".join(lines)


def main() -> None:
    torch.set_num_threads(THREADS)
    with tempfile.TemporaryDirectory() as tmp:
        path = write_random_smpl_npz(Path(tmp) / "random_smpl.npz", SEED)
        ctx = Context(model_path=path, model=BodyModel.from_file(path))
        rows = [row for measure in MEASUREMENTS for row in measure(ctx)]
    print(f"random SMPL-format model, {ctx.model.num_vertices} vertices, float32, {THREADS} threads\n")
    print(table(rows))
    print()
    print(skinning_table())


if __name__ == "__main__":
    main()
