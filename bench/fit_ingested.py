"""Stage 02 on what the ingest finds: bodies fitted from a video's 2D keypoints, with and without the metric 3D
keypoints (BlazePose's world landmarks) the ingest writes beside them, against the true bodies.

Each scenario is rendered at the `hd` fixture size (960x720, 60 frames over 3 s), encoded to a video and
ingested with the default parameters, as in bench/ingest.py. Stage 01 is left out: the fixture's own cameras
are used, so that the table measures the fit alone. Each found person is matched to the true person whose
visible masks it overlaps most, then every person is fitted (stage 02's defaults with the scene's overrides, as a
run would: one floor for everyone, the size prior the ingest writes)
three times (`--variants` picks): from the 2D keypoints only (2d: 02_smpl_fit.relative3d false), with the metric 3D
keypoints and their size (3d-size: relative3d_size model), and with them up to one size factor per person
(3d-fitted).
Per scene: mean per-joint error with no alignment, up to one scale for the whole scene about the camera (what no
single view tells: glimpse.fit.evaluate.scene_scale_errors) and after one similarity per person's sequence, pelvis
distance errors, depth order agreement (glimpse.fit.evaluate), how the metric 3D keypoints themselves
compare with the true body's (turned onto each frame's viewing ray as stage 02 does), and how the fitted body
moves (glimpse.fit.evaluate.motion_errors: jitter, and foot skate where the true foot is planted; '-' where it
never is); then the common floor against the true one (glimpse.fit.evaluate.floor_errors: its tilt, split
into the camera's pitch and roll, and the camera's height above it); and who hides whom where two people's
skeletons overlap in the image, as their ingested masks say it (glimpse.fit.evaluate.front_by_masks), against the
fitted and the true depth order.

    python bench/fit_ingested.py [--scenarios demo,adult_child] [--seed 0] [--work DIR]
                                 [--variants 2d,3d-size,3d-fitted] [--params "02_smpl_fit.key=value ..."]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections import Counter
from functools import cache
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ingest import fixture_video, found_people, true_people  # noqa: E402  (bench/ingest.py, beside this file)
from fit import order_cell  # noqa: E402  (bench/fit.py, beside this file)

from glimpse.body.keypoints import keypoint_map  # noqa: E402
from glimpse.body.model import BodyModel  # noqa: E402
from glimpse.body.model_file import SMPL_PARENTS  # noqa: E402
from glimpse.body.models import BodyModels  # noqa: E402
from glimpse.body.params import BodyParams  # noqa: E402
from glimpse.config import config_from_mapping, load_pipeline_yaml, parse_cli_params, resolve_params  # noqa: E402
from glimpse.fit.config import FitConfig  # noqa: E402
from glimpse.fit.evaluate import (  # noqa: E402
    body_joints,
    floor_errors,
    front_by_masks,
    joint_errors,
    motion_errors,
    placement_errors,
    scene_scale_errors,
    true_joints,
)
from glimpse.fit.stage import Fitter, onto_viewing_rays  # noqa: E402
from glimpse.fixtures.scenes import FREE_BODY  # noqa: E402
from glimpse.ingest.config import load_ingest_config  # noqa: E402
from glimpse.ingest.evaluate import match_frame  # noqa: E402
from glimpse.ingest.stage import ingest  # noqa: E402
from glimpse.io.cameras_json import read_cameras_json  # noqa: E402
from glimpse.io.images import read_mask  # noqa: E402
from glimpse.scene import load_scene, read_keypoints2d  # noqa: E402

SIZE = "hd"
SCENARIOS = ("demo", "adult_child", "lower_body_occluded", "crouch")
THREADS = 2
HIPS = (11, 12)  # COCO-17
# the metric 3D term: key -> (table label, 02_smpl_fit.relative3d, weights.relative3d_size)
VARIANTS = {"2d": ("no", False, "model"), "3d-size": ("its size", True, "model"),
            "3d-fitted": ("size fitted", True, "fitted")}
TRUE_UP, TRUE_FLOOR_HEIGHT = np.array([0.0, 1.0, 0.0]), 0.0  # the fixtures' world: y up, the floor at y = 0
# who hides whom from the masks (glimpse.fit.evaluate.front_by_masks): skeletons drawn 0.15 torso lengths wide,
# overlapping in at least 50 pixels, one mask covering at least half of the overlap and the other at most half as much
MASK_ORDER = {"radius_torsos": 0.15, "min_pixels": 50, "min_share": 0.5, "max_minority": 0.5}


def ingested_scene(scenario: str, seed: int, work: Path) -> tuple[Path, Path]:
    """(fixture folder, its video's ingested scene), each made only when not already in ``work``."""
    fixture, video = fixture_video(scenario, SIZE, seed, work)
    scene = work / f"{fixture.name}.ingested"
    if not (scene / "scene.yaml").exists():
        ingest(video, scene, load_ingest_config())
    return fixture, scene


def true_ids(fixture: Path, scene: Path) -> dict[str, str]:
    """Found pid -> the true pid it is matched to in most frames (by visible-mask IoU)."""
    truth = true_people(fixture, ("coco17_skin",))["coco17_skin"]
    found = found_people(scene)
    votes: dict[str, Counter] = {}
    for frame_id, people in truth.items():
        for true_pid, (found_pid, _) in match_frame(people, found.get(frame_id, {})).items():
            votes.setdefault(found_pid, Counter())[true_pid] += 1
    return {found_pid: counter.most_common(1)[0][0] for found_pid, counter in votes.items()}


def metric_keypoint_errors(model: BodyModel, scene: Path, truth_dir: Path, ids: dict[str, str],
                           cameras: dict) -> dict[str, float]:
    """How the scene's relative3d compare with the true bodies' COCO-17 joints relative to their mid hip, in
    the camera's axes, metres: mean error, and the ratio of their mean distance from the mid hip to the
    truth's (the model's idea of the person's size)."""
    coco = keypoint_map("coco17", model.data)
    errors, ratios = [], []
    for found_pid, true_pid in ids.items():
        kp = read_keypoints2d(scene / "humans" / found_pid / "keypoints2d.npz")
        body = np.load(truth_dir / f"{true_pid}_body.npz")
        rows = kp.frame_ids
        with torch.no_grad():
            out = model(torch.as_tensor(body["betas"])[None], torch.as_tensor(body["global_orient"][rows]),
                        torch.as_tensor(body["body_pose"][rows]), torch.as_tensor(body["transl"][rows]))
        joints = coco(out.joints, out.vertices).numpy()
        K = np.stack([cameras[int(f)].K for f in rows])
        R = np.stack([cameras[int(f)].R for f in rows])
        true = np.einsum("tij,tkj->tki", R, joints)
        true -= true[:, list(HIPS)].mean(1, keepdims=True)
        weight = kp.keypoints[..., 2]
        said = onto_viewing_rays(kp.relative3d[..., :3], kp.keypoints[..., :2], weight, K)
        used = (weight > 0) & (kp.relative3d[..., 3] > 0)
        errors.append(np.linalg.norm(said - true, axis=-1)[used])
        ratios.append(np.linalg.norm(said, axis=-1)[used].mean() / np.linalg.norm(true, axis=-1)[used].mean())
    return {"relative3d_error_m": float(np.concatenate(errors).mean()), "relative3d_size_ratio": float(np.mean(ratios))}


def mask_order(model: BodyModel, fitted: dict[str, BodyParams], truths: dict[str, dict[str, np.ndarray]],
               masks: dict[str, dict[int, Path]], cameras: dict) -> dict[str, int]:
    """Over every pair of people and frame both were fitted in: how many pair-frames the masks decide (who is in
    front where the fitted skeletons overlap), and of those how many the fitted and the true pelvis depths (along
    the camera's axis) put in the same order as the masks, and how many the fitted order agrees with the truth."""
    pelvis_depth, points = {}, {}
    for pid, params in fitted.items():
        keep = ~params.interpolated
        ours = body_joints(model, params.betas, params.global_orient[keep], params.body_pose[keep],
                           params.transl[keep], params.scale)
        true = true_joints(model, params, truths[pid])
        for frame, joints, truth in zip(params.frame_ids[keep], ours, true):
            camera = cameras[int(frame)]
            pixels, depth = camera.project(joints)
            points[pid, int(frame)] = pixels
            pelvis_depth[pid, int(frame)] = (depth[0], camera.project(truth[:1])[1][0])
    counts = {"decided": 0, "fitted_as_masks": 0, "true_as_masks": 0, "fitted_as_true": 0}
    frames = {pid: {f for p, f in points if p == pid} & set(masks[pid]) for pid in fitted}

    @cache
    def mask(pid: str, frame: int) -> np.ndarray:
        return read_mask(masks[pid][frame]) > 0

    pids = sorted(fitted)
    for k, a in enumerate(pids):
        for b in pids[k + 1:]:
            for frame in sorted(frames[a] & frames[b]):
                front = front_by_masks(points[a, frame], points[b, frame], mask(a, frame), mask(b, frame),
                                       SMPL_PARENTS, **MASK_ORDER)
                if front is None:
                    continue
                (fitted_a, true_a), (fitted_b, true_b) = pelvis_depth[a, frame], pelvis_depth[b, frame]
                masks_a_nearer, fitted_a_nearer, true_a_nearer = front == 0, fitted_a < fitted_b, true_a < true_b
                counts["decided"] += 1
                counts["fitted_as_masks"] += fitted_a_nearer == masks_a_nearer
                counts["true_as_masks"] += true_a_nearer == masks_a_nearer
                counts["fitted_as_true"] += fitted_a_nearer == true_a_nearer
    return counts


def floor_row(floor: dict, cameras: dict) -> dict:
    """The common floor's errors (glimpse.fit.evaluate.floor_errors) in the first frame's camera; {} without one."""
    if not floor.get("applied") or "normal" not in floor:
        return {}
    first = cameras[min(cameras)]
    return floor_errors(np.array(floor["normal"]), floor["camera_height"], np.array(floor["camera_centre"]),
                        first.R, TRUE_UP, TRUE_FLOOR_HEIGHT)


def run(scenario: str, seed: int, work: Path, model: BodyModel, variants: list[str], params: str) -> list[dict]:
    fixture, scene_dir = ingested_scene(scenario, seed, work)
    truth_dir = fixture.with_name(fixture.name + ".groundtruth")
    ids = true_ids(fixture, scene_dir)
    scene = load_scene(scene_dir)
    _, _, cameras = read_cameras_json(fixture / "cameras.json")
    centres = {fid: camera.centre for fid, camera in cameras.items()}
    metric = metric_keypoint_errors(model, scene_dir, truth_dir, ids, cameras)
    raw = resolve_params(load_pipeline_yaml(), scene.overrides, parse_cli_params(params))["02_smpl_fit"]  # as a run
    rows = []
    people = [person for pid, person in sorted(scene.humans.items()) if pid in ids]
    for variant, relative3d, size in (VARIANTS[key] for key in variants):
        weights = {**raw["weights"], "relative3d_size": size}
        config = config_from_mapping(FitConfig, {**raw, "overlay": False, "mode": "keypoints2d", "weights": weights,
                                                 "relative3d": relative3d}, "pipeline.yaml 02_smpl_fit")
        started = time.perf_counter()
        fits, floor = Fitter(scene, BodyModels(model), cameras, config, "metres").fit_people(people)
        seconds = time.perf_counter() - started
        fitted = {ids[fit.pid]: fit.params for fit in fits}
        truths = {pid: dict(np.load(truth_dir / f"{pid}_body.npz")) for pid in fitted}
        placement = placement_errors(model, fitted, truths, centres)
        scene_scale, scene_scaled = scene_scale_errors(model, fitted, truths, centres)
        frames = sum(int((~fit.interpolated).sum()) for fit in fitted.values())
        on_floor = floor_row(floor, cameras)
        found_masks = {ids[person.pid]: person.masks for person in people}
        order = mask_order(model, fitted, truths, found_masks, cameras)
        for pid, fit in sorted(fitted.items()):
            rows.append({"scenario": scenario, "person": pid, "variant": variant, "floor": floor["applied"],
                         "seconds_per_100_frames": 100 * seconds / frames, **placement, **metric,
                         **joint_errors(model, fit, truths[pid]), **motion_errors(model, fit, truths[pid], scene.fps),
                         "floor_errors": on_floor,
                         "scene_scale": scene_scale, "scene_scaled_m": scene_scaled[pid], "mask_order": order})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenarios", default=",".join(SCENARIOS))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--work", type=Path, default=None, help="keeps fixtures, videos and ingests between runs")
    parser.add_argument("--variants", default=",".join(VARIANTS),
                        help=f"which fits, of {', '.join(VARIANTS)} (2D keypoints only; with the metric 3D keypoints "
                             "at their size; with them up to a fitted size)")
    parser.add_argument("--params", default="",
                        help='stage-02 overrides, as make\'s PARAMS: "02_smpl_fit.key=value ..."')
    args = parser.parse_args()
    variants = args.variants.split(",")
    unknown = sorted(set(variants) - set(VARIANTS))
    if unknown:
        parser.error(f"--variants: unknown {', '.join(unknown)} (known: {', '.join(VARIANTS)})")
    torch.set_num_threads(THREADS)
    work = args.work or Path(tempfile.mkdtemp(prefix="glimpse-bench-fit-ingested-"))
    work.mkdir(parents=True, exist_ok=True)
    model = BodyModel.from_file(FREE_BODY, dtype=torch.float64)
    rows = [row for name in args.scenarios.split(",")
            for row in run(name, args.seed, work, model, variants, args.params)]
    print(f"\nStage 02 on ingested fixture videos ({SIZE}, seed {args.seed}, the fixtures' cameras); cm\n")
    print("| scene | person | metric 3D | floor | as fitted | up to one scene scale (the scale) | person-aligned | "
          "pelvis distances | depth order (largest true gap missed) | metric 3D keypoints' error | their size / true | "
          "jitter, m/s^3 (true) | foot skate, cm/s (true) | s per person per 100 frames |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        distance = r["pelvis_distance_error_m"]
        skate = (f"{100 * r['foot_skate_m_s']:.1f} ({100 * r['true_foot_skate_m_s']:.1f})" if r["contact_pairs"]
                 else "-")
        print(f"| {r['scenario']} | {r['person']} | {r['variant']} | "
              f"{'yes' if r['floor'] else 'no'} | {100 * r['mpjpe_m']:.1f} | "
              f"{100 * r['scene_scaled_m']:.1f} ({r['scene_scale']:.3f}) | {100 * r['sequence_aligned_m']:.1f} | "
              f"{'-' if np.isnan(distance) else f'{100 * distance:.1f}'} | "
              f"{order_cell(r['depth_order_agreement'], r['depth_order_largest_miss_m'])} | "
              f"{100 * r['relative3d_error_m']:.1f} | "
              f"{r['relative3d_size_ratio']:.2f} | {r['jitter_m_s3']:.0f} ({r['true_jitter_m_s3']:.0f}) | "
              f"{skate} | {r['seconds_per_100_frames']:.0f} |")

    print("\nThe common floor against the true one (degrees; the camera's height above it, cm; pitch: the fitted up "
          "leaning towards the camera's view)\n")
    print("| scene | metric 3D | tilt | pitch error | roll error | camera height error |")
    print("|---|---|---|---|---|---|")
    for r in {(r["scenario"], r["variant"]): r for r in rows}.values():
        f = r["floor_errors"]
        cells = (f"{f['tilt_deg']:.1f} | {f['pitch_error_deg']:+.1f} | {f['roll_error_deg']:+.1f} | "
                 f"{100 * f['camera_height_error_m']:+.0f}") if f else "no floor | - | - | -"
        print(f"| {r['scenario']} | {r['variant']} | {cells} |")

    print("\nWho hides whom, from the ingested masks where two fitted skeletons overlap (pair-frames), against the "
          "fitted and the true depth order\n")
    print("| scene | metric 3D | pair-frames the masks decide | fitted order as the masks | true order as the masks | "
          "fitted order as the truth there |")
    print("|---|---|---|---|---|---|")
    for r in {(r["scenario"], r["variant"]): r for r in rows}.values():
        o = r["mask_order"]
        print(f"| {r['scenario']} | {r['variant']} | {o['decided']} | {o['fitted_as_masks']} | {o['true_as_masks']} | "
              f"{o['fitted_as_true']} |")


if __name__ == "__main__":
    main()
