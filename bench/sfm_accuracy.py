"""Stage 01's structure from motion against the truth, on moving-camera fixtures (glimpse.fixtures, size
``sfm``: 256x192, 48 frames over 3 s; people masked from their masks).

For every fixture and seed, four variants: frames as rendered (PNG) or saved as JPEG (quality 90, as a
phone writes them: glimpse.fixtures.scenes.save_frames_as_jpeg), and intrinsics given (cameras.json's K,
fixed) or withheld (the focal length estimated: ``01_sfm.estimate_focal=true``). The fixture's true poses stay in cameras.json, so
stage 01 aligns its result to them by a similarity and reports the residual: camera-centre RMS and maximum
(metres, the fixture's units), the largest rotation error (degrees) and the estimated focal length's
relative error. Targets: every frame registered; centre RMS <= 1 cm and rotations <= 0.5 degrees with
intrinsics given; focal within 2% and centre RMS <= 2 cm with them withheld.

    python bench/sfm_accuracy.py [--fixtures moving_camera,follow_camera] [--seeds 0,1] [--work DIR]
"""

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from glimpse.fixtures.scenes import make_scene, save_frames_as_jpeg  # noqa: E402
from tests.stage_helpers import read_json, run  # noqa: E402

SIZE = "sfm"
FIXTURES = ("moving_camera", "follow_camera")
VARIANTS = (("png", False), ("jpeg", False), ("png", True), ("jpeg", True))  # (frames, focal estimated)


def as_jpeg(scene: Path, out: Path) -> Path:
    """A copy of ``scene`` whose frames are JPEG files (the PNGs re-encoded)."""
    if not out.exists():
        shutil.copytree(scene, out)
        save_frames_as_jpeg(out)
    return out


def measure(scene: Path, out: Path, estimate_focal: bool, extra_params: str) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    params = f"01_sfm.mode=sfm 01_sfm.estimate_focal={str(estimate_focal).lower()} {extra_params}".strip()
    start = time.perf_counter()
    stage = run("01_sfm", scene, out, params)
    wall = time.perf_counter() - start
    report = read_json(stage / "report.json")["sfm"]
    return {**report["error"], "registered": report["registered"], "frames": report["frames"],
            "points": report["points"], "s_per_frame": wall / report["frames"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--fixtures", default=",".join(FIXTURES))
    parser.add_argument("--seeds", default="0")
    parser.add_argument("--params", default="", help="extra pipeline parameters for stage 01")
    parser.add_argument("--work", type=Path, default=None, help="keeps the fixtures between runs")
    args = parser.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="glimpse-bench-sfm-"))
    rows = []
    for name in args.fixtures.split(","):
        for seed in map(int, args.seeds.split(",")):
            scene = work / f"{name}_{SIZE}_s{seed}"
            if not (scene / "scene.yaml").exists():
                make_scene(name, scene, SIZE, seed)
            for frames, estimate_focal in VARIANTS:
                source = scene if frames == "png" else as_jpeg(scene, work / f"{scene.name}_jpeg")
                result = measure(source, work / "out", estimate_focal, args.params)
                rows.append((name, seed, frames, estimate_focal, result))
                print(name, seed, frames, estimate_focal, {k: round(v, 5) for k, v in result.items()
                                                           if isinstance(v, float)}, flush=True)
    print(f"\nStage 01 (mode sfm) on fixtures at {SIZE} size; errors after similarity alignment to the true poses\n")
    print("| fixture (seed) | frames | intrinsics | registered | centre RMS (cm) | centre max (cm) "
          "| rotation max (deg) | focal error | points | s / frame |")
    print("|---|---|---|---|---:|---:|---:|---:|---:|---:|")
    for name, seed, frames, estimate_focal, r in rows:
        focal = f"{100 * r['focal_relative']:+.2f}%" if "focal_relative" in r else "given"
        intrinsics = "estimated" if estimate_focal else "given"
        print(f"| {name} ({seed}) | {frames} | {intrinsics} | {r['registered']}/{r['frames']} "
              f"| {100 * r['centre_rms_m']:.2f} | {100 * r['centre_max_m']:.2f} | {r['rotation_max_deg']:.3f} "
              f"| {focal} | {r['points']} | {r['s_per_frame']:.2f} |")


if __name__ == "__main__":
    main()
