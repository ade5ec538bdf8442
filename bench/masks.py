"""Stage 03 mask quality and time on the fixtures (body mode: masks from the bodies and frames).

For each scenario: stages 01 and 02 (bodies fitted from the 2D keypoints), then stage 03 in body
mode with each refinement (none, GrabCut, and for a static camera the background plate). Prints per scenario the IoU against the fixture's true visible
masks (mean over people of the per-frame mean, and pooled over all frames), the recall and
precision of the occluder masks against the true hidden part of each body (its projection where
the dressed person is not visible), and seconds per frame (2 threads). `--full` uses the
320x240, 100-frame scenes instead of the small ones.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from glimpse.body.model import BodyModel  # noqa: E402
from glimpse.fixtures.scenes import FREE_BODY, make_scene  # noqa: E402
from glimpse.io.cameras_json import read_cameras_json  # noqa: E402
from glimpse.io.images import frame_name, read_mask  # noqa: E402
from glimpse.masks.layers import body_layers  # noqa: E402
from tests.stage_helpers import read_json, run  # noqa: E402

THREADS = 2
SEED = 0
SCENARIOS = ("demo", "lower_body_occluded", "crowd", "moving_camera")
REFINES = ("none", "grabcut", "plate")  # plate only for static cameras


def true_hidden(scene: Path, model: BodyModel, pid: str, fid: int, camera, width: int, height: int) -> np.ndarray:
    truth = np.load(scene.with_name(scene.name + ".groundtruth") / f"{pid}_body.npz")
    with torch.no_grad():
        body = model(torch.as_tensor(truth["betas"])[None], torch.as_tensor(truth["global_orient"][fid:fid + 1]),
                     torch.as_tensor(truth["body_pose"][fid:fid + 1]), torch.as_tensor(truth["transl"][fid:fid + 1]))
    layers = body_layers([body.vertices[0].numpy()], [body.joints[0, 0].numpy()], model.faces.numpy(), camera,
                         width, height)
    return layers.full[0] & ~read_mask(scene / "humans" / pid / "masks" / f"{frame_name(fid)}.png")


def evaluate(size: str, root: Path) -> list[dict]:
    model = BodyModel.from_file(FREE_BODY, dtype=torch.float64)
    rows = []
    for scenario in SCENARIOS:
        scene = make_scene(scenario, root / f"{scenario}_{size}", size, seed=SEED)
        out = root / "out"
        run("01_sfm", scene, out)
        run("02_smpl_fit", scene, out, "02_smpl_fit.mode=keypoints2d 02_smpl_fit.overlay=false")
        _, _, cameras = read_cameras_json(scene / "cameras.json")
        width, height = read_mask(next((scene / "humans" / "p0" / "masks").iterdir())).shape[::-1]
        static = read_json(out / f"{scenario}_{size}" / "01_sfm" / "report.json")["camera_motion"] == "static"
        for refine in (r for r in REFINES if static or r != "plate"):
            started = time.perf_counter()
            result = run("03_masks", scene, out, f"03_masks.mode=body 03_masks.refine={refine}")
            seconds = (time.perf_counter() - started) / len(cameras)
            doc = read_json(result / "masks.json")
            inter = union = hit = hidden_total = flagged = 0
            for pid in doc["people"]:
                for fid, camera in cameras.items():
                    name = f"{frame_name(fid)}.png"
                    truth, ours = read_mask(scene / "humans" / pid / "masks" / name), read_mask(result / "masks" / pid / name)
                    inter, union = inter + (truth & ours).sum(), union + (truth | ours).sum()
                    hidden = true_hidden(scene, model, pid, fid, camera, width, height)
                    occluder = read_mask(result / "occluders" / pid / name)
                    hit, hidden_total, flagged = hit + (hidden & occluder).sum(), hidden_total + hidden.sum(), flagged + occluder.sum()
            rows.append({"scenario": scenario, "refine": refine, "people": len(doc["people"]),
                         "iou_mean": float(np.mean([v for v in doc["iou_vs_scene_masks"].values() if v is not None])),
                         "iou_pooled": inter / max(union, 1), "occluder_recall": hit / max(hidden_total, 1),
                         "occluder_precision": hit / max(flagged, 1), "seconds_per_frame": seconds,
                         "static": doc["static_scene"]})
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--full", action="store_true", help="the full-size scenes (minutes)")
    args = parser.parse_args()
    torch.set_num_threads(THREADS)
    size = "full" if args.full else "small"
    cache = Path(os.environ.get("GLIMPSE_CACHE", Path.home() / ".cache" / "glimpse")) / "bench_masks"
    cache.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=cache) as tmp:
        rows = evaluate(size, Path(tmp))
    print(f"\n### {size} fixtures, 03_masks mode body (bodies fitted from 2D keypoints)\n")
    print("| scenario | refine | people | IoU (mean of people) | IoU (pooled) | occluder recall | occluder precision | s/frame |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['scenario']} | {r['refine']} | {r['people']} | {r['iou_mean']:.3f} | {r['iou_pooled']:.3f} | "
              f"{r['occluder_recall']:.2f} | {r['occluder_precision']:.2f} | {r['seconds_per_frame']:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
