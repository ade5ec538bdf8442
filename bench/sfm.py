"""Stage 01 structure-from-motion timings (extraction, matching, mapping) on the
synthetic moving-camera room, at two frame sizes; ratios against the smallest
size measured in the same run. Camera-centre error after similarity alignment
is printed beside the times."""

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from glimpse.cameras.align import umeyama  # noqa: E402
from glimpse.io.cameras_json import read_cameras_json  # noqa: E402
from tests.stage_helpers import read_json, run  # noqa: E402
from tests.support.synthetic_room import make_room_scene  # noqa: E402

SIZES = [(160, 120), (320, 240), (640, 480)]
FRAMES = 24


def measure(width: int, height: int, root: Path) -> dict:
    truth = make_room_scene(root / "scene", n_frames=FRAMES, width=width, height=height, camera_motion="moving")
    start = time.perf_counter()
    out = run("01_sfm", root / "scene", root / "out")
    wall = time.perf_counter() - start
    timings = read_json(out / "manifest.json")["timings_s"]
    _, _, cameras = read_cameras_json(out / "cameras.json")
    ids = sorted(cameras)
    est = np.array([cameras[i].centre for i in ids])
    ref = np.array([truth.centres()[i] for i in ids])
    error = np.linalg.norm(umeyama(est, ref).apply(est) - ref, axis=1)
    return {"extraction": timings["extraction"], "matching": timings["matching"], "mapping": timings["mapping"],
            "stage": wall, "registered": len(ids), "error_mm": 1000 * error.max()}


def main() -> None:
    rows = []
    for width, height in SIZES:
        with tempfile.TemporaryDirectory() as tmp:
            rows.append(((width, height), measure(width, height, Path(tmp))))
    base = rows[0][1]["stage"]
    print(f"{FRAMES} frames, moving camera, person masked; 2 threads. Times in seconds.\n")
    print("| size | extraction | matching | mapping | whole stage | vs 160x120 | registered | max centre error (mm) |")
    print("|---|---|---|---|---|---|---|---|")
    for (w, h), r in rows:
        print(f"| {w}x{h} | {r['extraction']:.2f} | {r['matching']:.2f} | {r['mapping']:.2f} | {r['stage']:.2f} "
              f"| {r['stage'] / base:.2f}x | {r['registered']}/{FRAMES} | {r['error_mm']:.2f} |")


if __name__ == "__main__":
    main()
