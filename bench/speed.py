"""Novel-pose render speed (paper Table 5) and whole-scene speed, with stage 07's protocol
(glimpse/eval/speed.py, pipeline.yaml 07_eval.speed), 2 threads, the default backend.

The person: PERSON_GAUSSIANS Gaussians spread over the free body's canonical surface (area-weighted
samples, kNN scales, random colours, SH degree 2 with random higher bands, opacity 0.9), skinned by
the body's grid as stage 06 does; driven by the built-in walk, the camera circling the pelvis.
Baseline, same run: the same Gaussians rasterized in canonical pose with no posing (the renderer's
floor), so the ratio is what posing costs. The scene: SCENE_PEOPLE such people standing 1.5 m apart
and SCENE_BACKGROUND background Gaussians on the walls and floor of a 6 x 3 x 6 m room, seen from
eye height by the front wall at SCENE_SIZES.

    .venv/bin/python bench/speed.py [--quick] [--run OUT/demo]   (--run: a finished run's speed.json tables too)
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from glimpse.body.config import BodyConfig  # noqa: E402
from glimpse.body.model import BodyModel  # noqa: E402
from glimpse.body.models import BodyModels  # noqa: E402
from glimpse.body.params import BodyParams  # noqa: E402
from glimpse.body.skinning import bake_skin_weight_grid  # noqa: E402
from glimpse.cameras.model import PinholeCamera  # noqa: E402
from glimpse.config import config_from_mapping, load_pipeline_yaml  # noqa: E402
from glimpse.eval.config import SpeedConfig  # noqa: E402
from glimpse.eval.speed import (  # noqa: E402
    SpeedTiming,
    speed_markdown,
    speed_report,
    time_frames,
    time_novel_pose,
    time_scene,
)
from glimpse.gaussians.model import GaussianModel, knn_scales  # noqa: E402
from glimpse.humans.person import PersonGaussians, build_rig  # noqa: E402
from glimpse.render.config import RenderConfig  # noqa: E402
from glimpse.replay.finished import FinishedRun, load_finished_run  # noqa: E402
from glimpse.replay.motion import motion_from_spec  # noqa: E402

THREADS = 2
SEED = 0
PERSON_GAUSSIANS = 15_000  # the paper's Table 5 person
SH_DEGREE = 2
RENDER = RenderConfig("cpu", SH_DEGREE, antialiased=False)  # what the timings draw with
OPACITY = 0.9
KNN = 3  # neighbours of the initial scales (3DGS)
SCALE_FLOOR_M = 1e-3
SCENE_PEOPLE = 3
SCENE_BACKGROUND = 100_000
SCENE_SIZES = ((320, 240), (1280, 720))
SCENE_FRAMES = 10
ROOM_M = (6.0, 3.0, 6.0)  # width (x), height (y), depth (z); the floor at y = 0
BACKGROUND_SCALE_M = 0.03
SCENE_FOVY_DEG = 60.0


def surface_person(body_model: BodyModel, body: BodyConfig, count: int, rng: np.random.Generator,
                   pid: str = "p0", transl: np.ndarray | None = None) -> PersonGaussians:
    """``count`` Gaussians on the canonical body surface of the mean shape, skinned as stage 06 skins them;
    one frame (id 0) standing at ``transl`` (model frame + transl, metres)."""
    rig = build_rig(body_model, np.zeros(10), body.canonical_hip_angle_deg)
    vertices = rig.canonical_vertices.double().numpy()
    faces = body_model.faces.numpy()
    corners = vertices[faces]  # [F, 3, 3]
    areas = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    chosen = rng.choice(len(faces), size=count, p=areas / areas.sum())
    barycentric = rng.dirichlet(np.ones(3), size=count)
    points = np.einsum("nk,nkd->nd", barycentric, corners[chosen])
    grid = bake_skin_weight_grid(vertices, body_model.weights.double().numpy(), body.skinning.grid_resolution,
                                 body.skinning.grid_margin_m, body.skinning.knn, body.skinning.idw_power)
    model = GaussianModel.from_points(torch.as_tensor(points, dtype=torch.float32),
                                      torch.as_tensor(rng.uniform(0.1, 0.9, (count, 3)), dtype=torch.float32),
                                      torch.as_tensor(knn_scales(points, KNN, SCALE_FLOOR_M)), OPACITY, SH_DEGREE)
    with torch.no_grad():
        model.sh_rest.copy_(torch.as_tensor(rng.normal(0.0, 0.05, tuple(model.sh_rest.shape))))
    transl = np.zeros(3) if transl is None else transl
    params = BodyParams(np.array([0]), np.zeros(10), np.zeros((1, 3)), np.zeros((1, 69)), transl[None], 1.0,
                        "free", np.zeros(1, bool))
    return PersonGaussians(pid, model, grid, rig, params).freeze()


def room_background(count: int, rng: np.random.Generator) -> GaussianModel:
    """``count`` isotropic Gaussians (BACKGROUND_SCALE_M) on the floor and four walls of the room, random colours."""
    width, height, depth = ROOM_M
    plane = rng.integers(0, 5, count)  # 0 floor, 1-2 side walls (x = -+width/2), 3-4 back and front (z = -+depth/2)
    u, v = rng.uniform(0, 1, count), rng.uniform(0, 1, count)
    side = (plane == 1) | (plane == 2)
    x = np.where(side, (plane - 1.5) * width, (u - 0.5) * width)
    y = np.where(plane == 0, 0.0, v * height)
    z = np.select([plane == 0, side], [(v - 0.5) * depth, (u - 0.5) * depth], (plane - 3.5) * depth)
    points = np.stack([x, y, z], axis=1)
    return GaussianModel.from_points(torch.as_tensor(points, dtype=torch.float32),
                                     torch.as_tensor(rng.uniform(0.2, 0.8, (count, 3)), dtype=torch.float32),
                                     torch.full((count,), BACKGROUND_SCALE_M), OPACITY, SH_DEGREE)


def wall_camera(width: int, height: int) -> PinholeCamera:
    """A camera at eye height near the room's front wall, looking at the room's centre."""
    position = np.array([0.0, 1.6, 0.45 * ROOM_M[2]])
    target = np.array([0.0, 1.0, 0.0])
    forward = (target - position) / np.linalg.norm(target - position)
    right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    R = np.stack([right, np.cross(forward, right), forward])
    focal = 0.5 * height / math.tan(math.radians(SCENE_FOVY_DEG) / 2)
    K = np.array([[focal, 0.0, (width - 1) / 2], [0.0, focal, (height - 1) / 2], [0.0, 0.0, 1.0]])
    return PinholeCamera(K, R, -R @ position, width, height)


def canonical_baseline(person: PersonGaussians, size: int, config: SpeedConfig) -> SpeedTiming:
    """The same Gaussians rasterized in canonical pose from the same circling camera, with no posing."""
    from glimpse.cameras.model import render_camera
    from glimpse.cameras.orbit import turn_cameras
    from glimpse.render import rasterize

    device = torch.device("cpu")
    centre = person.rig.rest_joints[0].double().numpy()
    total = config.warmup_frames + config.frames
    inputs = person.model.render_inputs(SH_DEGREE)

    cameras = [render_camera(pinhole, device)
               for pinhole in turn_cameras(np.tile(centre, (total, 1)), config.radius_m, config.fovy_deg, size)]

    def draw(k: int, camera) -> int:
        rasterize(camera, **inputs, background=torch.ones(3), settings=RENDER)
        return len(person.model)

    def pose(k: int):
        return cameras[k]

    return time_frames(config.frames, config.warmup_frames, pose, draw, device, size, size)


def row(name: str, t: SpeedTiming, baseline: SpeedTiming | None = None) -> str:
    memory = "-" if t.peak_extra_mb is None else f"{t.peak_extra_mb:.0f}"
    ratio = f"{t.ms_per_frame / baseline.ms_per_frame:.2f}x" if baseline else "-"
    return (f"| {name} | {t.gaussians:,} | {t.width}x{t.height} | {t.ms_per_frame:.1f} | {t.fps:.1f} | "
            f"{t.posing_ms:.1f} | {t.raster_ms:.1f} | {memory} | {ratio} |")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="512² only, no whole scene")
    parser.add_argument("--run", type=Path, help="also time a finished run (OUT/<scene>) with stage 07's protocol")
    args = parser.parse_args()
    torch.manual_seed(SEED)
    torch.set_num_threads(THREADS)
    params = load_pipeline_yaml()
    body = config_from_mapping(BodyConfig, params["body"], "body")
    config = config_from_mapping(SpeedConfig, params["07_eval"]["speed"], "07_eval.speed")
    sizes = config.sizes_px[:1] if args.quick else config.sizes_px
    body_model = BodyModel.from_file(Path(__file__).resolve().parents[1] / "glimpse/body/assets/free_body.npz")
    rng = np.random.default_rng(SEED)
    person = surface_person(body_model, body, PERSON_GAUSSIANS, rng)
    motion = motion_from_spec(config.motion, config.motion_fps, config.frames / config.motion_fps)
    device = torch.device("cpu")

    header = ("| what | Gaussians | size | ms per frame | fps | posing ms | raster ms | peak extra MB | "
              "vs canonical |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    print(f"novel pose ({config.motion}), {THREADS} threads, cpu backend; median of {config.frames} frames; "
          f"'vs canonical': time per frame over the same Gaussians rasterized unposed (same run)\n")
    print(header)
    for size in sizes:
        baseline = canonical_baseline(person, size, config)
        print(row("canonical, no posing (baseline)", baseline), flush=True)
        timing = time_novel_pose(person, motion, size, config, RENDER, device)
        print(row("person, novel pose", timing, baseline), flush=True)
    if not args.quick:
        print(f"\nwhole scene: {SCENE_PEOPLE} such people and {SCENE_BACKGROUND:,} background Gaussians, "
              f"{SCENE_FRAMES} frames\n")
        print(header)
        people = [surface_person(body_model, body, PERSON_GAUSSIANS, rng, f"p{k}",
                                 np.array([1.5 * (k - (SCENE_PEOPLE - 1) / 2), 0.0, 0.0]))
                  for k in range(SCENE_PEOPLE)]
        background = room_background(SCENE_BACKGROUND, rng)
        for width, height in SCENE_SIZES:
            run = FinishedRun(Path("."), width, height, {0: wall_camera(width, height)}, background, people,
                              BodyModels(body_model), RENDER)
            timing = time_scene(run, [0] * SCENE_FRAMES, config.warmup_frames, device)
            print(row("whole scene", timing), flush=True)
    if args.run:
        print()
        print(speed_markdown(speed_report(load_finished_run(args.run), config, device)))


if __name__ == "__main__":
    main()
