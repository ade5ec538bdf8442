"""Structure from motion with pycolmap 4.x: SIFT on the CPU, sequential matching,
incremental mapping with a pinhole camera (PINHOLE with K fixed when known, else
SIMPLE_PINHOLE with its focal length estimated from the frame pairs first, glimpse.sfm.focal),
and a last robust bundle adjustment; or triangulation from known poses (docs/cameras.md).

People are cut out of feature extraction with COLMAP masks (black = no features).
Known intrinsics are given to COLMAP and kept fixed. COLMAP's pixel convention
puts the top-left pixel centre at (0.5, 0.5); conversion happens here and only here.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pycolmap

from glimpse.cameras.model import PinholeCamera
from glimpse.errors import GlimpseError
from glimpse.io.colmap_model import PINHOLE_MODELS, colmap_intrinsics
from glimpse.io.colmap_text import COLMAP_PIXEL_OFFSET
from glimpse.io.images import parse_frame_name, write_png
from glimpse.sfm.focal import focal_from_fundamentals
from glimpse.sfm.person_regions import PersonRegions

log = logging.getLogger("glimpse")


@dataclass(frozen=True)
class SfmOptions:
    """COLMAP settings (pipeline.yaml 01_sfm and compute)."""

    max_features: int
    max_image_size: int
    peak_threshold: float  # SIFT's DoG peak threshold (lower: more features on low-contrast surfaces)
    domain_size_pooling: bool  # SIFT descriptors pooled over several scales (DSP-SIFT)
    sequential_overlap: int
    min_num_matches: int
    refine: bool  # after mapping: drop badly reprojected points, bundle-adjust everything with a robust loss
    refine_rounds: int
    refine_max_error_px: float
    refine_loss_scale_px: float
    focal_min_pairs: int  # frame pairs with a fundamental matrix needed to self-calibrate the focal length
    focal_fov_range_deg: tuple[float, float]  # fields of view (across the longer side) searched
    threads: int
    seed: int
    deterministic: bool  # COLMAP on one thread, so reruns give identical files


@dataclass
class SfmResult:
    """cameras: frame id -> camera (SfM's own world frame and units, OpenCV pixels);
    xyz (N, 3) / rgb (N, 3) uint8: sparse points; timings_s: extraction, matching, mapping."""

    cameras: dict[int, PinholeCamera]
    xyz: np.ndarray
    rgb: np.ndarray
    num_models: int
    timings_s: dict[str, float] = field(default_factory=dict)
    self_calibration: dict | None = None  # focal length from the frame pairs (intrinsics estimated only)


def _write_colmap_masks(folder: Path, frames: dict[int, Path], regions: PersonRegions, shape: tuple[int, int]) -> None:
    """COLMAP masks: ``<image name>.png``, 255 where features may be extracted, 0 on people."""
    folder.mkdir(parents=True, exist_ok=True)
    for fid, path in frames.items():
        allowed = ~regions.exclusion(fid, shape)
        write_png(folder / f"{path.name}.png", allowed.astype(np.uint8) * 255)


def _colmap_params(K: np.ndarray, model: str) -> str:
    """COLMAP's parameter string of a PINHOLE (fx, fy, cx, cy) or SIMPLE_PINHOLE (f, cx, cy) camera with K."""
    focal = (K[0, 0], K[1, 1]) if model == "PINHOLE" else (K[0, 0],)
    return ",".join(f"{v:.12g}" for v in (*focal, K[0, 2] + COLMAP_PIXEL_OFFSET, K[1, 2] + COLMAP_PIXEL_OFFSET))


def _camera_K(camera: pycolmap.Camera) -> np.ndarray:
    """(3, 3) OpenCV K of a COLMAP PINHOLE or SIMPLE_PINHOLE camera."""
    if camera.model_name not in PINHOLE_MODELS:
        raise GlimpseError(f"COLMAP returned a {camera.model_name} camera; expected a pinhole model")
    return colmap_intrinsics(camera.model_name, [float(p) for p in camera.params], "COLMAP's camera")[0]


def _extract_and_match(
    work: Path, frames: dict[int, Path], regions: PersonRegions, shape: tuple[int, int],
    K: np.ndarray, fixed_K: bool, options: SfmOptions, timings: dict[str, float],
) -> Path:
    """SIFT features (people masked) and sequential matches into ``work/database.db``."""
    pycolmap.logging.minloglevel = pycolmap.logging.Level.WARNING.value  # COLMAP's INFO lines flood the log
    image_dir = next(iter(frames.values())).parent
    database = work / "database.db"
    database.unlink(missing_ok=True)
    mask_dir = work / "colmap_masks"
    _write_colmap_masks(mask_dir, frames, regions, shape)
    reader = pycolmap.ImageReaderOptions()
    reader.mask_path = mask_dir
    # known intrinsics, kept fixed; else square pixels, principal point at the centre: one focal length to
    # estimate, starting from K's
    model = "PINHOLE" if fixed_K else "SIMPLE_PINHOLE"
    reader.camera_model = model
    reader.camera_params = _colmap_params(K, model)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = _colmap_threads(options)  # image ids follow completion order
    extraction.max_image_size = options.max_image_size
    extraction.sift.max_num_features = options.max_features
    extraction.sift.peak_threshold = options.peak_threshold
    extraction.sift.domain_size_pooling = options.domain_size_pooling
    log.info("SfM: extracting SIFT features from %d frames", len(frames))
    start = time.perf_counter()
    pycolmap.extract_features(
        database, image_dir, image_names=[p.name for _, p in sorted(frames.items())],
        camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader, extraction_options=extraction,
        device=pycolmap.Device.cpu,
    )
    timings["extraction"] = round(time.perf_counter() - start, 3)
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = _colmap_threads(options)
    pairing = pycolmap.SequentialPairingOptions()
    pairing.overlap = options.sequential_overlap
    pairing.num_threads = _colmap_threads(options)
    log.info("SfM: sequential matching (overlap %d)", options.sequential_overlap)
    start = time.perf_counter()
    pycolmap.match_sequential(database, matching_options=matching, pairing_options=pairing, device=pycolmap.Device.cpu)
    timings["matching"] = round(time.perf_counter() - start, 3)
    return database


def _colmap_threads(options: SfmOptions) -> int:
    """COLMAP threads. Every step's result depends on thread scheduling: extraction numbers the
    images in completion order, verification draws RANSAC samples per thread, bundle
    adjustment sums in varying order. Deterministic runs use one thread."""
    return 1 if options.deterministic else options.threads


def _pipeline_options(options: SfmOptions, fixed_intrinsics: bool) -> pycolmap.IncrementalPipelineOptions:
    pipeline = pycolmap.IncrementalPipelineOptions()
    pipeline.num_threads = _colmap_threads(options)
    pipeline.random_seed = options.seed
    pipeline.min_num_matches = options.min_num_matches
    pipeline.mapper.random_seed = options.seed
    pipeline.mapper.num_threads = _colmap_threads(options)
    pipeline.triangulation.random_seed = options.seed
    pipeline.ba_refine_principal_point = False
    pipeline.ba_refine_extra_params = False
    if fixed_intrinsics:
        pipeline.ba_refine_focal_length = False
        pipeline.mapper.abs_pose_refine_focal_length = False
        pipeline.mapper.abs_pose_refine_extra_params = False
    return pipeline


def _result_from_reconstruction(rec: pycolmap.Reconstruction, num_models: int, timings: dict[str, float]) -> SfmResult:
    cameras = {}
    for image in rec.images.values():
        if not image.has_pose:
            continue
        fid = frame_id_of(image.name)
        pose = image.cam_from_world()
        camera = rec.cameras[image.camera_id]
        cameras[fid] = PinholeCamera(
            K=_camera_K(camera),
            R=np.asarray(pose.rotation.matrix(), dtype=np.float64),
            t=np.asarray(pose.translation, dtype=np.float64),
            width=int(camera.width), height=int(camera.height),
        )
    points = list(rec.points3D.values())
    xyz = np.array([p.xyz for p in points], dtype=np.float64).reshape(-1, 3)
    rgb = np.array([p.color for p in points], dtype=np.uint8).reshape(-1, 3)
    return SfmResult(cameras=cameras, xyz=xyz, rgb=rgb, num_models=num_models, timings_s=timings)


def run_sfm(
    work: Path, frames: dict[int, Path], regions: PersonRegions, shape: tuple[int, int],
    K: np.ndarray, fixed_K: bool, options: SfmOptions,
) -> SfmResult:
    """Estimate every frame's camera; keep the largest model. K: the intrinsics, kept when ``fixed_K``, else
    the starting point of the focal length's estimate."""
    work.mkdir(parents=True, exist_ok=True)
    timings: dict[str, float] = {}
    database = _extract_and_match(work, frames, regions, shape, K, fixed_K, options, timings)
    self_calibration = None if fixed_K else _self_calibrate(database, shape, options)
    log.info("SfM: incremental mapping")
    start = time.perf_counter()
    # An estimated focal length stays fixed while the model grows and is refined at the end (_refine)
    models = pycolmap.incremental_mapping(database, next(iter(frames.values())).parent, work / "sparse",
                                          _pipeline_options(options, fixed_intrinsics=fixed_K or options.refine))
    timings["mapping"] = round(time.perf_counter() - start, 3)
    if not models:
        raise GlimpseError(
            "structure from motion found no model: too few matches between frames "
            "(a textureless or mostly-masked scene, or too little camera motion). "
            "If the camera is static, set camera_motion: static in scene.yaml or PARAMS=01_sfm.mode=static"
        )
    largest = max(models.values(), key=lambda rec: rec.num_reg_images())
    log.info("SfM: %d model(s); the largest registers %d of %d frames", len(models), largest.num_reg_images(), len(frames))
    if options.refine:
        start = time.perf_counter()
        _refine(largest, options, fixed_K)
        timings["refinement"] = round(time.perf_counter() - start, 3)
    result = _result_from_reconstruction(largest, len(models), timings)
    result.self_calibration = self_calibration
    return result


def _self_calibrate(database: Path, shape: tuple[int, int], options: SfmOptions) -> dict:
    """Set the database camera's focal length to the one its frame pairs' fundamental matrices agree on
    (glimpse.sfm.focal) when at least ``options.focal_min_pairs`` pairs have one, else keep the start;
    returns what was done."""
    db = pycolmap.Database.open(database)
    try:
        _, geometries = db.read_two_view_geometries()
        (camera,) = db.read_all_cameras()
        start_focal, cx, cy = (float(v) for v in camera.params)
        with_f = {pycolmap.TwoViewGeometryConfiguration.CALIBRATED, pycolmap.TwoViewGeometryConfiguration.UNCALIBRATED}
        fundamentals = np.array([g.F for g in geometries if g.config in with_f and np.abs(g.F).sum() > 0])
        report = {"pairs": len(fundamentals), "start_focal_px": start_focal, "focal_px": None}
        if len(fundamentals) >= options.focal_min_pairs:
            report["focal_px"] = focal_from_fundamentals(fundamentals.reshape(-1, 3, 3), np.array([cx, cy]),
                                                         max(shape), options.focal_fov_range_deg)
            camera.params = [report["focal_px"], cx, cy]
            db.update_camera(camera)
    finally:
        db.close()
    if report["focal_px"] is None:
        log.info("SfM: %d frame pairs with a fundamental matrix (< 01_sfm.focal_min_pairs %d): the focal length "
                 "starts at %.1f px (01_sfm.static_fov_deg)", report["pairs"], options.focal_min_pairs, start_focal)
    else:
        log.info("SfM: focal length %.1f px from %d frame pairs (start %.1f px)", report["focal_px"], report["pairs"],
                 start_focal)
    return report


def _refine(rec: pycolmap.Reconstruction, options: SfmOptions, fixed_K: bool) -> None:
    """``options.refine_rounds`` times: drop the points whose mean reprojection error exceeds
    ``options.refine_max_error_px``, then bundle-adjust every pose and point (and the focal length unless
    ``fixed_K``) with a robust (Cauchy) loss."""
    ba = pycolmap.BundleAdjustmentOptions()
    ba.refine_focal_length = not fixed_K
    ba.refine_principal_point = False
    ba.refine_extra_params = False
    ba.print_summary = False
    ba.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
    ba.ceres.loss_function_scale = options.refine_loss_scale_px
    ba.ceres.solver_options.num_threads = _colmap_threads(options)
    for _ in range(options.refine_rounds):
        rec.update_point_3d_errors()
        for point_id in [i for i, point in rec.points3D.items() if point.error > options.refine_max_error_px]:
            rec.delete_point3D(point_id)
        pycolmap.bundle_adjustment(rec, ba)


def triangulate_known_poses(
    work: Path, frames: dict[int, Path], regions: PersonRegions, shape: tuple[int, int],
    cameras: dict[int, PinholeCamera], options: SfmOptions,
) -> SfmResult:
    """Sparse points from given per-frame cameras (features and matches as run_sfm, no pose estimation)."""
    work.mkdir(parents=True, exist_ok=True)
    timings: dict[str, float] = {}
    first_K = next(iter(cameras.values())).K
    database = _extract_and_match(work, frames, regions, shape, first_K, True, options, timings)
    start = time.perf_counter()
    db = pycolmap.Database.open(database)
    try:
        rec = pycolmap.Reconstruction()
        db_cameras = db.read_all_cameras()
        for camera in db_cameras:
            rec.add_camera(camera)
        for rig in db.read_all_rigs():
            rec.add_rig(rig)
        images = db.read_all_images()
        image_of_frame = {image.frame_id: image for image in images}
        for frame in db.read_all_frames():
            cam = cameras[frame_id_of(image_of_frame[frame.frame_id].name)]
            if not np.allclose(cam.K, first_K):
                raise GlimpseError("triangulation from given poses needs one shared K (per-frame K is not supported)")
            frame.rig_from_world = pycolmap.Rigid3d(np.hstack([cam.R, cam.t[:, None]]))
            rec.add_frame(frame)
        for image in images:
            rec.add_image(image)
        for frame_id in list(rec.frames):
            rec.register_frame(frame_id)
    finally:
        db.close()
    out = work / "triangulated"
    out.mkdir(exist_ok=True)
    rec = pycolmap.triangulate_points(rec, database, next(iter(frames.values())).parent, out,
                                      options=_pipeline_options(options, fixed_intrinsics=True))
    timings["triangulation"] = round(time.perf_counter() - start, 3)
    result = _result_from_reconstruction(rec, 1, timings)
    result.cameras = dict(cameras)  # the given cameras are the truth; only points come from COLMAP
    return result


def frame_id_of(image_name: str) -> int:
    fid = parse_frame_name(Path(image_name).stem)
    if fid is None:
        raise GlimpseError(f"COLMAP returned an image {image_name!r} that is not a frame")
    return fid


