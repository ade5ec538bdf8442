"""Stage 01: cameras and initial background points.

Inputs:  the scene (frames/ or video.mp4, cameras.json, humans/*/masks, keypoints2d for masking people).
Params:  01_sfm, compute (pipeline.yaml).
Outputs (OUT/<scene>/01_sfm/, CONTRACTS.md):
  frames/<id>.png|jpg   the frames every later stage reads (undistorted, subsampled)
  cameras.json          glimpse-cameras/1, one camera per frame that has one
  points.ply            glimpse-points/1, sparse points with colours (moving cameras only)
  colmap/               COLMAP text model (cameras.txt, images.txt, points3D.txt)
  report.json           glimpse-cameras-report/1: mode, camera motion, frames without camera, SfM error
"""

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from glimpse.compute import apply_compute, resolved_threads  # noqa: E402
from glimpse.io.cameras_json import CAMERAS_FORMAT, write_cameras_json  # noqa: E402
from glimpse.io.colmap_text import write_colmap_text  # noqa: E402
from glimpse.io.ply_points import POINTS_FORMAT, write_points_ply  # noqa: E402
from glimpse.pipeline.runner import StageContext, stage_main  # noqa: E402
from glimpse.scene import load_scene  # noqa: E402
from glimpse.sfm.stage import estimate_cameras  # noqa: E402

STAGE = "01_sfm"
REPORT_FORMAT = "glimpse-cameras-report/1"


def run(ctx: StageContext) -> None:
    config = ctx.section(STAGE)
    compute = ctx.section("compute")
    apply_compute(compute)
    scene = load_scene(ctx.scene_root, checked=True)
    with ctx.timed("stage"):
        outcome = estimate_cameras(scene, config, ctx.out / "frames", ctx.work / "colmap_work",
                                   resolved_threads(compute), compute.seed)
    if not outcome.cameras:
        raise RuntimeError("stage 01 produced no camera")  # estimate_cameras raises a clear error first
    write_cameras_json(ctx.out / "cameras.json", scene.width, scene.height, outcome.cameras)
    ctx.formats["cameras.json"] = CAMERAS_FORMAT
    has_points = outcome.xyz is not None and len(outcome.xyz) > 0
    if has_points:
        write_points_ply(ctx.out / "points.ply", outcome.xyz, outcome.rgb)
        ctx.formats["points.ply"] = POINTS_FORMAT
    ext = {fid: p.suffix for fid, p in outcome.frames.items()}
    write_colmap_text(ctx.out / "colmap", scene.width, scene.height, outcome.cameras,
                      image_ext=next(iter(ext.values())),
                      xyz=outcome.xyz if has_points else None, rgb=outcome.rgb if has_points else None)
    ctx.formats["colmap/"] = "colmap-text"
    report = {
        "format": REPORT_FORMAT,
        "mode": outcome.mode,
        "mode_reason": outcome.mode_reason,
        "camera_motion": outcome.camera_motion,
        "units": outcome.units,
        "frames": len(outcome.frame_ids),
        "frames_with_camera": len(outcome.cameras),
        "frames_without_camera": outcome.frames_without_camera,
        "motion": outcome.motion,
        "sfm": outcome.sfm,
        "undistorted": scene.cameras is not None and scene.cameras.dist is not None,
        "warnings": outcome.warnings,
    }
    (ctx.out / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    ctx.formats["report.json"] = REPORT_FORMAT
    ctx.timings.update(outcome.timings_s)
    ctx.summary.update({k: report[k] for k in ("mode", "camera_motion", "units", "frames", "frames_with_camera")})
    if outcome.sfm and "error" in outcome.sfm:
        ctx.summary["sfm_error"] = outcome.sfm["error"]


if __name__ == "__main__":
    stage_main(STAGE, run, __doc__)
