"""The ingest (glimpse ingest VIDEO SCENE_DIR) on fixture scenes with known people.

Each scenario is rendered at the `hd` fixture size (960x720, 60 frames over 3 s, people 250-450 px tall as in a
phone video), its frames are encoded to an H.264 video and everything else is set aside; the video is ingested
with the default parameters and the result compared with the ground truth (glimpse.ingest.evaluate): per
person, detection recall over frames where the person is at least half visible, identity switches, PCK of the
COCO-17 keypoints in view at 10% of the torso size against the true ones projected by the true camera (in view:
not hidden by anyone or anything, the person's own body included, which is decided on a depth render of the
true body), and the mask IoU against the true visible mask. PCK is given against two definitions of the true COCO-17 points: as annotators
mark them on the skin (`coco17_skin`, anny's COCO regressor; what keypoint detectors are trained on) and the
body model's joint centres (`coco17`, what the fixtures' own keypoints and stage 02 use). Speed: scene frames per second of the
tracking pass on this machine, and milliseconds per frame per person.

With --model-reference, also what the keypoint model gives each person when it is shown them alone: in every
frame, the other people's visible pixels replaced by the fixture's true background and the landmark model's
region placed from the person's true joints (as MediaPipe's alignment places it, then re-centred as the
tracker does), then the ingest's own keypoint steps (the median over moved and mirrored crops, the confidence
threshold, left, right and legs kept consistent along the track, smoothing), and the segmentation snapped to the
frame's edges as the written masks are. Tracking that found everyone and painted the others perfectly would give
about that (the tracker's regions differ: not a strict bound); where the ingest falls short of it, the tracker
lost the person or their keypoints, and where it is itself under the target, the model is (its PCK and IoU count
the same joints and frames as the ingest's).

    python bench/ingest.py [--scenarios demo,crowd] [--seed 0] [--work DIR] [--params "ingest.key=value ..."]
                           [--model-reference]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from glimpse.body.keypoints import keypoint_map
from glimpse.body.model import BodyModel
from glimpse.fixtures.mesh_render import Mesh, render_meshes
from glimpse.fixtures.scenes import FREE_BODY, make_scene
from glimpse.ingest.behind import region_from_keypoints
from glimpse.ingest.blazepose import REGION_GROW, BlazePose
from glimpse.ingest.config import IngestConfig, load_ingest_config
from glimpse.ingest.crop import Region
from glimpse.ingest.evaluate import (HALF_VISIBLE, FoundPerson, TruePerson, in_front_of_own_body, mask_iou, pck,
                                     score_people)
from glimpse.ingest.mask_snap import snapped_masks
from glimpse.ingest.sides import consistent_sides
from glimpse.ingest.smoothing import smooth_keypoints
from glimpse.ingest.stage import blazepose_folder, ingest, user_pose
from glimpse.ingest.tracker import Tracker, recorded_keypoints
from glimpse.io.images import frame_files, read_mask, read_rgb
from glimpse.io.video import write_mp4
from glimpse.scene import load_scene

SIZE = "hd"
SCENARIOS = ("demo", "crowd", "moving_camera", "lower_body_occluded", "adult_child", "crouch", "unseen_clothes")
PCK_FRACTION = 0.1
JOINT_MASK_REACH_PX = 2  # a joint counts as visible when the person's visible mask is within this many pixels
OWN_BODY_MARGIN_M = 0.05  # a joint is behind its own body when deeper than this past its own skin (clothing, curvature)


def true_people(scene_dir: Path, layouts: tuple[str, ...]) -> dict[str, dict[int, dict[str, TruePerson]]]:
    """Layout (coco17_skin | coco17) -> frame id -> pid -> the true visible mask and COCO-17 points of a fixture
    scene. Which joints are in view (not behind the person's own body) is decided on the skin points, for
    every layout: the same anatomical joints."""
    truth_dir = scene_dir.with_name(scene_dir.name + ".groundtruth")
    scene = load_scene(scene_dir)
    model = BodyModel.from_file(FREE_BODY, dtype=torch.float64)
    maps = {layout: keypoint_map(layout, model.data) for layout in layouts}
    skin = keypoint_map("coco17_skin", model.data)
    faces = model.faces.numpy()
    cameras = json.loads((scene_dir / "cameras.json").read_text())
    K = np.array(cameras["K"])
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * JOINT_MASK_REACH_PX + 1,) * 2)
    out: dict[str, dict[int, dict[str, TruePerson]]] = {layout: {} for layout in layouts}
    for pid in scene.humans:
        body = np.load(truth_dir / f"{pid}_body.npz")
        for fid in scene.frame_ids:
            with torch.no_grad():
                posed = model(torch.as_tensor(body["betas"])[None], torch.as_tensor(body["global_orient"][fid:fid + 1]),
                              torch.as_tensor(body["body_pose"][fid:fid + 1]), torch.as_tensor(body["transl"][fid:fid + 1]))
            mask = read_mask(scene_dir / "humans" / pid / "masks" / f"{fid:06d}.png")
            grown = cv2.dilate(mask.astype(np.uint8), kernel) > 0
            h, w = mask.shape
            pose = cameras["frames"][f"{fid:06d}"]
            R, t = np.array(pose["R"]), np.array(pose["t"])
            vertices = posed.vertices[0].numpy()
            in_view = _in_view(skin(posed.joints, posed.vertices)[0].numpy(), vertices,
                               render_meshes([Mesh(vertices, faces, np.ones_like(vertices))], K, R, t, w, h,
                                             supersample=1).depth, K, R, t)
            for layout, coco in maps.items():
                uv, px, _, inside = _project(coco(posed.joints, posed.vertices)[0].numpy(), K, R, t, w, h)
                visible = inside.copy()
                visible[inside] = grown[px[inside, 1], px[inside, 0]]
                out[layout].setdefault(fid, {})[pid] = TruePerson(mask, uv, visible, in_view)
    return out


def _in_view(points: np.ndarray, vertices: np.ndarray, body_depth: np.ndarray, K: np.ndarray, R: np.ndarray,
             t: np.ndarray) -> np.ndarray:
    """[J] bool: points [J, 3] (world, on or under the skin of the body whose posed vertices [V, 3] rendered
    alone give body_depth [H, W]) that are not behind that body (glimpse.ingest.evaluate.in_front_of_own_body)."""
    h, w = body_depth.shape
    _, px, depth, inside = _project(points, K, R, t, w, h)
    front = np.zeros(len(points))
    front[inside] = body_depth[px[inside, 1], px[inside, 0]]
    under_skin = np.linalg.norm(vertices[None] - points[:, None], axis=2).min(axis=1)
    return in_front_of_own_body(depth, front, under_skin, OWN_BODY_MARGIN_M)


def _project(points: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray, w: int, h: int
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """World points [J, 3] through a pinhole camera -> (pixels [J, 2], nearest pixel [J, 2] int, camera depth
    [J], [J] bool: in front of the camera and on a pixel of the w x h image)."""
    cam = points @ R.T + t
    uv = cam[:, :2] / cam[:, 2:3] * [K[0, 0], K[1, 1]] + K[:2, 2]
    px = np.round(uv).astype(int)
    inside = (cam[:, 2] > 0) & (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
    return uv, px, cam[:, 2], inside


def found_people(scene_dir: Path) -> dict[int, dict[str, FoundPerson]]:
    """Frame id -> pid -> the ingested mask and keypoints."""
    out: dict[int, dict[str, FoundPerson]] = {}
    for person_dir in sorted((scene_dir / "humans").iterdir()):
        keypoints = np.load(person_dir / "keypoints2d.npz")
        masks = frame_files(person_dir / "masks")
        for fid, kp in zip(keypoints["frame_ids"].tolist(), keypoints["keypoints"]):
            out.setdefault(fid, {})[person_dir.name] = FoundPerson(read_mask(masks[fid]), kp)
    return out


def fixture_video(scenario: str, size: str, seed: int, work: Path) -> tuple[Path, Path]:
    """(fixture scene folder, its frames as an H.264 video) in ``work``, made only when not already there."""
    fixture = work / f"{scenario}_{size}_s{seed}"
    if not (fixture / "scene.yaml").exists():
        make_scene(scenario, fixture, size, seed)
    video = work / f"{fixture.name}.mp4"
    if not video.exists():
        scene = load_scene(fixture)
        write_mp4(video, (read_rgb(scene.frame_paths[f]) for f in scene.frame_ids), scene.fps)
    return fixture, video


def reference_region(joints: np.ndarray) -> Region:
    """The landmark model's region for a person whose COCO-17 points [17, 2] (pixels, hidden ones too) are known,
    as MediaPipe's alignment places it (glimpse.ingest.behind.region_from_keypoints, every point counted), grown
    as the model's crop is."""
    return region_from_keypoints(joints, np.ones(len(joints), bool), REGION_GROW)


class ModelReference(NamedTuple):
    """What the models give one person shown alone (module docstring), over the frames where they are at least
    half visible."""

    pck: float       # PCK@PCK_FRACTION of the joints in view
    mask_iou: float  # the segmentation, snapped to the frame's edges as the ingest's masks are, against the true
                     # visible mask (0 in a frame where the model found nobody)


def model_reference(fixture: Path, truth: dict[int, dict[str, TruePerson]], config: IngestConfig
                    ) -> dict[str, ModelReference]:
    """Pid -> what the ingest's steps give when the model is shown each person alone (module docstring), counted
    over the same joints and frames as the ingest's scores. The fixture's frames must be at the tracking size (its
    longer side at most ``track_max_side``)."""
    scene = load_scene(fixture)
    backgrounds = frame_files(fixture.with_name(fixture.name + ".groundtruth") / "background")
    tracker = Tracker(BlazePose(blazepose_folder(config), config.threads), config, None, pose=user_pose(config))
    people = sorted({pid for frame in truth.values() for pid in frame})
    snap_radius = round(config.mask_snap_radius * max(scene.width, scene.height))  # as the ingest's written masks
    out = {}
    for pid in people:
        frames, keypoints, disputes, ious = [], [], [], []
        for fid in sorted(truth):
            person = truth[fid].get(pid)
            if person is None or not person.visible.any():
                continue
            image, background = read_rgb(scene.frame_paths[fid]), read_rgb(backgrounds[fid])
            for other, someone in truth[fid].items():
                if other != pid:
                    image[someone.mask] = background[someone.mask]
            observation = tracker.observe(image, reference_region(person.joints))
            counted = person.visible.mean() >= HALF_VISIBLE
            if observation is None:
                ious += [0.0] if counted else []
                continue
            if counted:
                mask = snapped_masks(image, [observation.mask], snap_radius, config.mask_snap_eps)[0]
                ious.append(mask_iou(person.mask, mask))
            tracker.written_keypoints(image, observation)
            frames.append(fid)
            keypoints.append(recorded_keypoints(observation.keypoints, image.shape[:2], config.keypoint_min_confidence))
            disputes.append(observation.legs_disputed)
        by_frame = {}
        if frames:
            ids = np.array(frames)
            consistent = consistent_sides(ids, np.stack(keypoints), np.zeros((len(ids), 17, 4)), np.array(disputes),
                                          scene.camera_motion == "static", scene.fps, config)[0]
            by_frame = dict(zip(frames, smooth_keypoints(ids, consistent, config.keypoint_smoothing_frames)))
        correct, counted = 0, 0
        for fid in sorted(truth):
            person = truth[fid].get(pid)
            if person is None or person.visible.mean() < HALF_VISIBLE:
                continue
            found = by_frame.get(fid)
            right, seen = pck(person.joints, person.seen, found, PCK_FRACTION) if found is not None else (
                0, int(person.seen.sum()))
            correct, counted = correct + right, counted + seen
        out[pid] = ModelReference(correct / counted if counted else float("nan"),
                                  float(np.mean(ious)) if ious else float("nan"))
    return out


def run(scenario: str, size: str, seed: int, work: Path, params: str = "", reference: bool = False) -> list[dict]:
    fixture, video = fixture_video(scenario, size, seed, work)
    ingested = work / f"{fixture.name}.ingested"
    config = load_ingest_config(params)
    report = ingest(video, ingested, config)
    found = found_people(ingested)
    truth = true_people(fixture, ("coco17_skin", "coco17"))
    scores = score_people(truth["coco17_skin"], found, PCK_FRACTION)
    references = model_reference(fixture, truth["coco17_skin"], config) if reference else {}
    joint_scores = score_people(truth["coco17"], found, PCK_FRACTION)
    people = max(len(report["people"]), 1)
    rows = []
    for pid, s in scores.items():
        rows.append({"scenario": scenario, "person": pid, "frames": s.frames, "recall": s.recall,
                     "switches": s.switches, "pck": s.pck, "pck_joints": joint_scores[pid].pck,
                     "pck_silhouette": s.pck_silhouette, "hidden_reported": s.hidden_reported,
                     "outside_reported": s.outside_reported,
                     "mask_iou": s.mask_iou, "ids": ",".join(s.ids), "reference": references.get(pid),
                     "fps": report["tracking_fps"], "ms_per_person": 1000 / report["tracking_fps"] / people,
                     "camera": report["camera_motion"]})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenarios", default=",".join(SCENARIOS))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--size", default=SIZE, help="fixture size (default hd: 960x720)")
    parser.add_argument("--work", type=Path, default=None, help="keeps fixtures and videos between runs")
    parser.add_argument("--params", default="", help='ingest overrides, as make\'s PARAMS: "ingest.key=value ..."')
    parser.add_argument("--model-reference", action="store_true",
                        help="also the PCK and mask IoU the models give each person shown alone (module docstring)")
    args = parser.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="glimpse-bench-ingest-"))
    work.mkdir(parents=True, exist_ok=True)
    rows = [row for name in args.scenarios.split(",") for row in run(name, args.size, args.seed, work, args.params,
                                                                          args.model_reference)]
    print(f"\nIngest on fixture videos ({args.size}, seed {args.seed}); targets: recall >= 0.95, switches 0, "
          f"PCK@{PCK_FRACTION} >= 0.90, mask IoU >= 0.85\n")
    print("PCK over the joints in view (not behind anyone or anything, the person's own body included); "
          "'on silhouette' also counts joints behind the person's own body (a side-on person's far arm), and "
          "'hidden reported' is the share of those the ingest gave a confidence > 0; 'outside reported' the share of "
          "the joints outside the image it gave one ('-': none outside); 'model shown alone': the PCK and the mask IoU "
          "the models give the person shown alone (--model-reference; '-': not asked for)\n")
    print("| scenario | camera | person | frames (>= half visible) | recall | switches | PCK@0.1 skin | "
          "PCK@0.1 skin, model shown alone | PCK@0.1 joint centres | PCK@0.1 skin, on silhouette | hidden reported | "
          "outside reported | mask IoU | mask IoU, model shown alone | found as | tracking fps | ms / frame / person |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        outside = "-" if np.isnan(r["outside_reported"]) else f"{r['outside_reported']:.2f}"
        reference, reference_iou = ("-", "-") if r["reference"] is None else (f"{r['reference'].pck:.3f}",
                                                                             f"{r['reference'].mask_iou:.3f}")
        print(f"| {r['scenario']} | {r['camera']} | {r['person']} | {r['frames']} | {r['recall']:.3f} | {r['switches']} "
              f"| {r['pck']:.3f} | {reference} | {r['pck_joints']:.3f} | {r['pck_silhouette']:.3f} "
              f"| {r['hidden_reported']:.2f} | {outside} | {r['mask_iou']:.3f} | {reference_iou} | {r['ids']} "
              f"| {r['fps']:.2f} | {r['ms_per_person']:.0f} |")


if __name__ == "__main__":
    main()
