"""Stage 01's logic: choose the camera mode, materialise frames, estimate cameras.

Modes (CONTRACTS.md, world frame):
  provided  cameras.json per-frame poses; their world frame. Points triangulated when the camera moves.
  static    one fixed camera: R = I, t = 0 (world = camera frame); K given or from a default field of view.
  sfm       pycolmap; SfM's own frame and units, or, when the scene gives poses (forced sfm), the
            result aligned to them by a similarity and the residual reported as the SfM error.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from glimpse.cameras.align import align_cameras
from glimpse.cameras.model import PinholeCamera, camera_from_pose, default_intrinsics
from glimpse.cameras.undistort import scene_undistorter
from glimpse.errors import GlimpseError
from glimpse.io.images import frame_name
from glimpse.scene import Scene
from glimpse.sfm.config import CamerasConfig
from glimpse.sfm.frames import select_frame_ids, write_frames
from glimpse.sfm.motion import measure_camera_motion
from glimpse.sfm.person_regions import find_person_regions

if TYPE_CHECKING:  # COLMAP is loaded only when the camera moves: a static-camera run needs no pycolmap
    from glimpse.sfm.colmap import SfmOptions

log = logging.getLogger("glimpse")

NO_PERSON_CUES_WARNING = (
    "no person masks or 2D keypoints in the scene: people cannot be cut out of feature extraction, "
    "and moving people may corrupt the camera poses (give humans/<pid>/masks/ or keypoints2d.npz)"
)
NO_PEOPLE_WARNING = (
    "the scene lists no people (humans/): if anyone moves in the video, moving people may corrupt the "
    "camera poses (give humans/<pid>/masks/ or keypoints2d.npz)"
)


@dataclass
class CamerasOutcome:
    """What stage 01 found. cameras: frame id -> camera for every frame that has one."""

    mode: str
    mode_reason: str
    camera_motion: str  # "static" | "moving"
    frame_ids: list[int]
    frames: dict[int, Path]
    cameras: dict[int, PinholeCamera]
    units: str  # "metres" | "sfm"
    xyz: np.ndarray | None = None
    rgb: np.ndarray | None = None
    motion: dict | None = None
    sfm: dict | None = None
    warnings: list[str] = field(default_factory=list)
    timings_s: dict[str, float] = field(default_factory=dict)

    @property
    def frames_without_camera(self) -> list[int]:
        return [fid for fid in self.frame_ids if fid not in self.cameras]


def _given_poses(scene: Scene) -> dict[int, PinholeCamera]:
    if scene.cameras is None:
        return {}
    given = scene.cameras
    return {fid: camera_from_pose(given.K, pose.R, pose.t, given.width, given.height, pose.K)
            for fid, pose in given.poses.items()}


def _is_static(cameras: dict[int, PinholeCamera], tolerance_m: float) -> bool:
    """True when every camera centre lies within ``tolerance_m`` of the others and all
    rotations agree to the same tolerance (on a unit sphere: radians)."""
    centres = np.array([c.centre for c in cameras.values()])
    rotations = np.array([c.R for c in cameras.values()])
    return bool(np.ptp(centres, axis=0).max() <= tolerance_m and np.ptp(rotations, axis=0).max() <= tolerance_m)


def choose_mode(scene: Scene, config: CamerasConfig) -> tuple[str, str]:
    """(mode, reason) before any measurement; mode "measure" means: decide from the frames."""
    if config.mode != "auto":
        return config.mode, "forced by 01_sfm.mode"
    if scene.cameras is not None and scene.cameras.poses:
        return "provided", "cameras.json gives per-frame poses"
    if scene.camera_motion == "static":
        return "static", "scene.yaml camera_motion: static"
    if scene.camera_motion == "moving":
        return "sfm", "scene.yaml camera_motion: moving, no per-frame poses"
    if scene.has_3d_person_data():
        return "static", "3D person data without per-frame poses is in the static camera's frame"
    return "measure", ""


def _sfm_options(config: CamerasConfig, threads: int, seed: int) -> SfmOptions:
    from glimpse.sfm.colmap import SfmOptions

    return SfmOptions(
        max_features=config.sift_max_features, max_image_size=config.sift_max_image_size,
        peak_threshold=config.sift_peak_threshold, domain_size_pooling=config.sift_domain_size_pooling,
        sequential_overlap=config.sequential_overlap,
        min_num_matches=config.min_num_matches, refine=config.refine, refine_rounds=config.refine_rounds,
        refine_max_error_px=config.refine_max_error_px, refine_loss_scale_px=config.refine_loss_scale_px,
        focal_min_pairs=config.focal_min_pairs, focal_fov_range_deg=tuple(config.focal_fov_range_deg),
        threads=threads, seed=seed, deterministic=config.deterministic,
    )


def estimate_cameras(
    scene: Scene, config: CamerasConfig, frames_dir: Path, work: Path, threads: int, seed: int
) -> CamerasOutcome:
    """Run stage 01: frames into ``frames_dir``, cameras and points in the returned outcome."""
    mode, reason = choose_mode(scene, config)
    given = _given_poses(scene)
    if mode == "provided" and not given:
        raise GlimpseError("01_sfm.mode=provided needs cameras.json with per-frame poses (\"frames\")")
    if mode == "static" and given and scene.has_3d_person_data():
        raise GlimpseError(
            "01_sfm.mode=static would replace the poses of cameras.json, but the scene's 3D person data "
            "is in their world frame; use mode provided or sfm"
        )
    frame_ids = select_frame_ids(scene.frame_ids, scene.fps, config.fps, config.max_frames)
    K_input = scene.cameras.K if scene.cameras is not None else None
    undistorter = scene_undistorter(scene)
    frames = write_frames(scene, frame_ids, undistorter, frames_dir)
    regions = find_person_regions(
        scene, frame_ids, undistorter, config.person_mask_dilate, config.keypoint_min_confidence, config.keypoint_box_margin
    )
    outcome_args: dict = {"frame_ids": frame_ids, "frames": frames}
    warnings: list[str] = []
    if undistorter.active:
        warnings.append("frames were undistorted with cameras.json dist; scene masks and 2D keypoints are in the "
                        "original (distorted) pixels")

    motion = None
    if mode == "measure":
        measure = measure_camera_motion(frames, regions, config.motion_sample_frames, config.motion_min_tracked_fraction)
        moving = measure.motion > config.motion_threshold
        mode = "sfm" if moving else "static"
        reason = (f"camera_motion unknown: measured background motion {measure.motion:.4g} of the image diagonal "
                  f"{'>' if moving else '<='} threshold {config.motion_threshold}")
        motion = {"measure": measure.motion, "threshold": config.motion_threshold, "corners": measure.corners,
                  "per_frame": {frame_name(k): v for k, v in measure.per_frame.items()}}
    log.info("mode %s (%s)", mode, reason)

    if mode == "static":
        K = K_input if K_input is not None else default_intrinsics(scene.width, scene.height, config.static_fov_deg)
        cameras = {fid: PinholeCamera(K, np.eye(3), np.zeros(3), scene.width, scene.height) for fid in frame_ids}
        return CamerasOutcome(mode, reason, "static", cameras=cameras, units="metres", motion=motion,
                              warnings=warnings, **outcome_args)

    if not regions.sources:
        warnings.append(NO_PERSON_CUES_WARNING if scene.humans else NO_PEOPLE_WARNING)
        log.warning(warnings[-1])
    shape = (scene.height, scene.width)

    if mode == "provided":
        cameras = {fid: given[fid] for fid in frame_ids if fid in given}
        if _is_static(cameras, config.static_pose_tolerance_m):
            return CamerasOutcome(mode, reason, "static", cameras=cameras, units="metres", warnings=warnings,
                                  **outcome_args)
        from glimpse.sfm.colmap import triangulate_known_poses

        result = triangulate_known_poses(work, {f: frames[f] for f in cameras}, regions, shape, cameras,
                                         _sfm_options(config, threads, seed))
        return CamerasOutcome(mode, reason, "moving", cameras=cameras, units="metres", xyz=result.xyz, rgb=result.rgb,
                              warnings=warnings, timings_s=result.timings_s,
                              sfm={"masking": list(regions.sources), "points": int(len(result.xyz))}, **outcome_args)

    # sfm
    known_K = None
    if scene.cameras is not None and not config.estimate_focal:
        per_frame_K = {fid: c.K for fid, c in given.items()}
        if any(not np.allclose(k, scene.cameras.K) for k in per_frame_K.values()):
            raise GlimpseError("01_sfm.mode=sfm with per-frame K (zoom) is not supported: use mode provided")
        known_K = scene.cameras.K
    from glimpse.sfm.colmap import run_sfm

    start_K = known_K if known_K is not None else default_intrinsics(scene.width, scene.height, config.static_fov_deg)
    result = run_sfm(work, frames, regions, shape, start_K, known_K is not None, _sfm_options(config, threads, seed))
    registered = len(result.cameras) / len(frame_ids)
    sfm_report = {"masking": list(regions.sources), "models": result.num_models, "registered": len(result.cameras),
                  "frames": len(frame_ids), "intrinsics": "fixed (cameras.json)" if known_K is not None else "estimated",
                  "points": int(len(result.xyz))}
    if result.self_calibration is not None:
        sfm_report["self_calibration"] = result.self_calibration
    if registered < config.min_registered_fraction:
        missing = [fid for fid in frame_ids if fid not in result.cameras]
        raise GlimpseError(
            f"structure from motion registered {len(result.cameras)} of {len(frame_ids)} frames "
            f"({registered:.0%} < 01_sfm.min_registered_fraction {config.min_registered_fraction:.0%}); "
            f"unregistered: {', '.join(map(str, missing[:20]))}{' ...' if len(missing) > 20 else ''}. "
            "Check the frames overlap and show texture, mask the people, or lower the fraction."
        )
    cameras, xyz, units = result.cameras, result.xyz, "sfm"
    if given:
        cameras, xyz, sfm_report["error"] = _align_to_given(cameras, xyz, given)
        units = "metres"
        if known_K is None:  # focal estimated, a true one given: how far off
            estimated = next(iter(result.cameras.values())).K[0, 0]
            sfm_report["error"]["focal_relative"] = float(estimated / scene.cameras.K[0, 0] - 1)
    return CamerasOutcome(mode, reason, "moving", cameras=cameras, units=units, xyz=xyz, rgb=result.rgb,
                          motion=motion, sfm=sfm_report, warnings=warnings, timings_s=result.timings_s, **outcome_args)


def _align_to_given(
    cameras: dict[int, PinholeCamera], xyz: np.ndarray, given: dict[int, PinholeCamera]
) -> tuple[dict[int, PinholeCamera], np.ndarray, dict]:
    """Similarity-align SfM cameras to the given ones (centres and viewing axes); report the residual (metres)."""
    common = sorted(set(cameras) & set(given))
    if len(common) < 3:
        raise GlimpseError(f"cannot align SfM to the given cameras: only {len(common)} frames in common (need 3)")
    sim = align_cameras({f: cameras[f] for f in common}, {f: given[f] for f in common})
    aligned = {fid: sim.apply_to_camera(cam) for fid, cam in cameras.items()}
    errors = np.array([np.linalg.norm(aligned[f].centre - given[f].centre) for f in common])
    rot_errors = [
        np.degrees(np.arccos(np.clip((np.trace(aligned[f].R @ given[f].R.T) - 1) / 2, -1, 1))) for f in common
    ]
    report = {"centre_rms_m": float(np.sqrt((errors**2).mean())), "centre_median_m": float(np.median(errors)),
              "centre_max_m": float(errors.max()), "rotation_max_deg": float(max(rot_errors)),
              "alignment_scale": sim.scale, "frames_compared": len(common)}
    return aligned, sim.apply(xyz) if len(xyz) else xyz, report
