"""Video only vs people given: the whole pipeline on a scene the ingest made from a video, against the same
scene with the fixture's own 2D keypoints and masks.

The `demo` fixture (two people crossing, one cut by the frame border) is rendered at 480x360 (30 frames) and
encoded to a video. Three scenes share the same frames (the ingest's, downscaled to 128x96, the size `make demo`
runs at) and the same held-out views (the fixture's, moved into the input camera's frame and downscaled); none has
cameras.json, and only the third has 3D person data:

- video only: people, 2D keypoints and masks from `glimpse ingest` (found and tracked at 480x360), and the stage-02
  setting the ingest writes into its scenes (02_smpl_fit.weights.size_sigma);
- given 2D: the fixture's 2D keypoints (noise 1.5 px at 320 px, 10% dropped) and true visible masks;
- video only, bodies from 3D: the video-only scene plus the fixture's 3D keypoints (noise 1.5 cm, moved into the
  input camera's frame), which stage 02 then fits instead of the 2D ones: the same run with bodies as good as 3D
  keypoints give, so the difference to "video only" is what fitting bodies to one video's 2D evidence costs.

All run every stage with the default parameters and their scene.yaml overrides (`make all`); the table gives
stage 07's humans-only PSNR, SSIM and LPIPS on the held-out views (GTU's protocol) and the differences. Takes
about 35 minutes on 2 cores.

    python bench/ingest_end_to_end.py [--seed 0] [--work DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.ingest import fixture_video  # noqa: E402
from glimpse.ingest.config import load_ingest_config  # noqa: E402
from glimpse.ingest.stage import ingest  # noqa: E402
from glimpse.io.images import read_mask, read_rgb  # noqa: E402
from glimpse.io.video import resized  # noqa: E402
from glimpse.scene import Scene, SceneWriter, load_scene, read_keypoints2d, read_keypoints3d  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SCENARIO, SIZE = "demo", "medium"
RUN_SIDE = 128  # the scenes' frame size (longer side), as `make demo`
MASK_COVERAGE = 0.5
MIN_SAME_PERSON_IOU = 0.3  # a found person and a true one are the same when their masks overlap this much


def _small_mask(mask: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    return resized(mask.astype(np.float32), size) > MASK_COVERAGE


def _scaled_K(K: np.ndarray, scale: float) -> np.ndarray:
    """Intrinsics for an image scaled by ``scale`` (pixel centres at integers)."""
    out = np.array(K, float)
    out[:2, :2] *= scale
    out[:2, 2] = (out[:2, 2] + 0.5) * scale - 0.5
    return out


def _same_people(found: Scene, truth: Scene, size: tuple[int, int]) -> dict[str, str]:
    """``found``'s person id -> ``truth``'s, by the mean mask IoU over the frames both have (at ``size``), the
    best pairs first; a found person overlapping nobody (IoU under ``MIN_SAME_PERSON_IOU``) gets none."""
    iou = {}
    for pid, person in found.humans.items():
        for tid, true_person in truth.humans.items():
            shared = sorted(set(person.masks) & set(true_person.masks))
            scores = []
            for fid in shared:
                a = _small_mask(read_mask(person.masks[fid]), size)
                b = _small_mask(read_mask(true_person.masks[fid]), size)
                scores.append((a & b).sum() / max((a | b).sum(), 1))
            iou[pid, tid] = float(np.mean(scores)) if scores else 0.0
    matched: dict[str, str] = {}
    for (pid, tid), score in sorted(iou.items(), key=lambda item: -item[1]):
        if score >= MIN_SAME_PERSON_IOU and pid not in matched and tid not in matched.values():
            matched[pid] = tid
    return matched


def compose(out: Path, frames_from: Path, people_from: Path, fixture: Path, name: str,
            keypoints3d_from: Path | None = None) -> Path:
    """A scene with ``frames_from``'s frames, ``people_from``'s keypoints2d and masks (scaled to the frames) and
    the fixture's held-out views in the input camera's frame; with ``keypoints3d_from``, that scene's 3D keypoints
    too (in the input camera's frame)."""
    frames_scene, people_scene, truth = load_scene(frames_from), load_scene(people_from), load_scene(fixture)
    size = (frames_scene.width, frames_scene.height)
    scale = frames_scene.width / people_scene.width
    writer = SceneWriter(out, name, frames_scene.fps, "static",
                         overrides=people_scene.overrides)  # the ingest's stage-02 setting comes with its people
    for fid in frames_scene.frame_ids:
        writer.frame(fid, read_rgb(frames_scene.frame_paths[fid]))
    for pid, person in people_scene.humans.items():
        keypoints = read_keypoints2d(person.keypoints2d)
        points = keypoints.keypoints.copy()
        found = points[..., 2:] > 0
        points[..., :2] = np.where(found, (points[..., :2] + 0.5) * scale - 0.5, 0.0)
        writer.keypoints2d(pid, keypoints.frame_ids, keypoints.layout, points)
        for fid, path in person.masks.items():
            writer.person_mask(pid, fid, _small_mask(read_mask(path), size))
    cameras = json.loads((fixture / "cameras.json").read_text())
    first = cameras["frames"][min(cameras["frames"])]
    R_c, t_c = np.array(first["R"]), np.array(first["t"])
    if keypoints3d_from is not None:
        source = load_scene(keypoints3d_from)
        for pid, source_pid in _same_people(people_scene, source, size).items():
            given = read_keypoints3d(source.humans[source_pid].keypoints3d)
            joints = given.joints.copy()
            joints[..., :3] = joints[..., :3] @ R_c.T + t_c
            writer.keypoints3d(pid, given.frame_ids, given.layout, joints)
    eval_scale = frames_scene.width / truth.width
    for cam, view in truth.eval_cameras.items():
        R = view.R @ R_c.T
        writer.eval_camera(cam, *size, _scaled_K(view.K, eval_scale), R, view.t - R @ t_c)
        for fid, path in view.images.items():
            people = {pid: _small_mask(read_mask(masks[fid]), size)  # the fixture's pids: only where they are ours
                      for pid, masks in view.person_masks.items() if fid in masks and people_from == fixture}
            writer.eval_view(cam, fid, resized(read_rgb(path), size),
                             _small_mask(read_mask(view.union_masks[fid]), size), people)
    return writer.finish()


def run_pipeline(scene: Path, out: Path) -> dict:
    env = dict(os.environ, OMP_WAIT_POLICY="passive")
    subprocess.run(["make", "--no-print-directory", "all", f"SCENE={scene}", f"OUT={out}"], cwd=REPO, check=True,
                   env=env)
    name = load_scene(scene).name
    doc = json.loads((out / name / "07_eval" / "metrics.json").read_text())
    return doc["tables"]["humans"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--work", type=Path, default=None)
    args = parser.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="glimpse-bench-e2e-"))
    work.mkdir(parents=True, exist_ok=True)
    fixture, video = fixture_video(SCENARIO, SIZE, args.seed, work)
    from dataclasses import replace

    ingested = work / "ingested"
    ingest(video, ingested, replace(load_ingest_config(), max_side=RUN_SIDE))
    scenes = {"video only (glimpse ingest)": compose(work / "video_only", ingested, ingested, fixture, "video_only"),
              "given 2D keypoints and masks": compose(work / "given_2d", ingested, fixture, fixture, "given_2d"),
              "video only, bodies from 3D keypoints": compose(work / "video_only_3d", ingested, ingested, fixture,
                                                              "video_only_3d", keypoints3d_from=fixture)}
    results = {label: run_pipeline(path, work / "runs") for label, path in scenes.items()}
    print(f"\nHeld-out humans-only metrics, {SCENARIO} fixture (seed {args.seed}), {RUN_SIDE} px frames\n")
    print("| people from | PSNR (dB) | SSIM | LPIPS x100 |")
    print("|---|---|---|---|")
    psnr = {}
    for label, table in results.items():
        row = table["rows"][0]
        psnr[label] = row["psnr"]
        print(f"| {label} | {row['psnr']:.2f} | {row['ssim']:.4f} | {row['lpips']:.2f} |")
    video_only, given, bodies_3d = psnr.values()
    print(f"\nvideo only - given: {video_only - given:+.2f} dB (target: within 1.5 dB)")
    print(f"video only - the same with bodies from 3D keypoints: {video_only - bodies_3d:+.2f} dB (target: within 1 dB)")


if __name__ == "__main__":
    main()
