"""What the viewer (``glimpse view``) costs per frame: its live and sharp renders of a canvas, on the same
synthetic scene as bench/speed.py (SCENE_PEOPLE people of PERSON_GAUSSIANS Gaussians and SCENE_BACKGROUND
background Gaussians in a room), against render_shot from the same camera in the same run (the viewer's floor:
its session adds the state lookups and the locking). Sizes: pipeline.yaml's view.preview_max_side_px and
view.still_max_side_px for a CANVAS browser canvas. 2 threads, the cpu backend.

    .venv/bin/python bench/viewer.py [--frames N]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench._timing import median_seconds  # noqa: E402
from bench.speed import (  # noqa: E402
    PERSON_GAUSSIANS,
    RENDER,
    SCENE_BACKGROUND,
    SCENE_PEOPLE,
    SEED,
    THREADS,
    room_background,
    surface_person,
    wall_camera,
)
from glimpse.body.config import BodyConfig  # noqa: E402
from glimpse.body.model import BodyModel  # noqa: E402
from glimpse.body.models import BodyModels  # noqa: E402
from glimpse.config import config_from_mapping, load_pipeline_yaml  # noqa: E402
from glimpse.replay.finished import FinishedRun  # noqa: E402
from glimpse.replay.render import Edits, render_shot  # noqa: E402
from glimpse.view.camera import render_size  # noqa: E402
from glimpse.view.config import ViewConfig  # noqa: E402
from glimpse.view.session import ViewSession  # noqa: E402

CANVAS = (1280, 720)  # a browser window's canvas, pixels
WARMUP = 2


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--frames", type=int, default=10, help="timed frames per row (median reported)")
    args = parser.parse_args()
    torch.manual_seed(SEED)
    torch.set_num_threads(THREADS)
    params = load_pipeline_yaml()
    body = config_from_mapping(BodyConfig, params["body"], "body")
    view = config_from_mapping(ViewConfig, params["view"], "view")
    body_model = BodyModel.from_file(Path(__file__).resolve().parents[1] / "glimpse/body/assets/free_body.npz")
    rng = np.random.default_rng(SEED)
    people = [surface_person(body_model, body, PERSON_GAUSSIANS, rng, f"p{k}",
                             np.array([1.5 * (k - (SCENE_PEOPLE - 1) / 2), 0.0, 0.0])) for k in range(SCENE_PEOPLE)]
    background = room_background(SCENE_BACKGROUND, rng)
    camera = wall_camera(*CANVAS)
    run = FinishedRun(Path("."), CANVAS[0], CANVAS[1], {0: camera}, background, people, BodyModels(body_model), RENDER)
    session = ViewSession(run, view, torch.device("cpu"))
    total = SCENE_PEOPLE * PERSON_GAUSSIANS + SCENE_BACKGROUND
    print(f"viewer renders, {SCENE_PEOPLE} people x {PERSON_GAUSSIANS:,} + {SCENE_BACKGROUND:,} background = "
          f"{total:,} Gaussians, canvas {CANVAS[0]}x{CANVAS[1]}, {THREADS} threads, cpu backend; median of "
          f"{args.frames} frames; 'vs render_shot': over the same frame drawn by render_shot (same run)\n")
    print("| render | size | ms per frame | fps | vs render_shot |\n|---|---:|---:|---:|---:|")
    for label, side in (("live (camera moving)", view.preview_max_side_px), ("sharp (camera at rest)",
                                                                              view.still_max_side_px)):
        shot = camera.resized(*render_size(*CANVAS, side))
        floor = 1000.0 * median_seconds(lambda: render_shot(run, shot, 0, Edits(), torch.device("cpu")),
                                        args.frames, WARMUP)
        ms = 1000.0 * median_seconds(lambda: session.render(shot), args.frames, WARMUP)
        print(f"| {label} | {shot.width}x{shot.height} | {ms:.1f} | {1000.0 / ms:.1f} | {ms / floor:.2f} |",
              flush=True)


if __name__ == "__main__":
    main()
