"""Stage 03's logic: per frame with a camera, every person's visible mask, the union, and each
person's occluder mask, written as PNGs, with the depth order and (where the scene has masks
and the masks were computed) the IoU against them.

Modes: ``provided`` uses the scene's masks (undistorted like the frames); ``body`` computes them
from stage 02's bodies (glimpse.masks.assign) and, for a static camera, the frames' background
plate (glimpse.masks.plate) and static-scene evidence (glimpse.masks.static); ``onnx-sam`` asks
the user's Segment Anything model, prompted with each person's visible joints
(glimpse.masks.sam); ``auto`` is ``provided`` when every person has a mask in every frame, else
``body``. Lengths in pipeline.yaml are metres at the person, turned into pixels per frame with the
focal length, the pelvis depth and the person's scale (world units per metre).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from glimpse.body.model import BodyModel
from glimpse.body.models import BodyModels
from glimpse.body.params import BodyParams
from glimpse.cameras.model import PinholeCamera
from glimpse.cameras.undistort import scene_undistorter
from glimpse.errors import GlimpseError
from glimpse.io.images import frame_files, frame_name, read_mask, read_rgb, write_png
from glimpse.io.progress import progress
from glimpse.masks.assign import (
    FrameMasks,
    body_frame_masks,
    plate_refiner,
    provided_frame_masks,
    static_in_front,
)
from glimpse.masks.config import MasksConfig
from glimpse.masks.layers import BodyLayers, body_layers
from glimpse.masks.plate import Plate, median_plate
from glimpse.masks.refine import grabcut_region
from glimpse.masks.sam import SamOnnx
from glimpse.masks.static import SurfaceMotion, temporal_std
from glimpse.morphology import disk
from glimpse.scene import Scene

MASKS_FORMAT = "glimpse-masks/1"
MIN_PELVIS_DEPTH = 1e-3  # world units: a pelvis nearer than this to the camera plane grows nothing


@dataclass(frozen=True)
class MasksInputs:
    scene: Scene
    models: BodyModels  # each person's body model
    cameras: dict[int, PinholeCamera]
    bodies: dict[str, BodyParams]  # stage 02's, per person
    frames_dir: Path  # stage 01's frames/
    camera_motion: str  # stage 01's "static" | "moving"


def choose_mode(inputs: MasksInputs, config: MasksConfig) -> str:
    complete = all(set(inputs.cameras) <= set(person.masks) for person in inputs.scene.humans.values())
    if config.mode == "provided" and not complete:
        missing = [pid for pid, person in sorted(inputs.scene.humans.items()) if not set(inputs.cameras) <= set(person.masks)]
        raise GlimpseError(f"03_masks.mode=provided needs humans/<pid>/masks/<frame>.png for every frame with a camera; "
                           f"missing for {', '.join(missing)}")
    if config.mode == "auto":
        return "provided" if complete else "body"
    return config.mode


def static_scene(inputs: MasksInputs, config: MasksConfig, paths: dict[int, Path]) -> tuple[np.ndarray | None, str]:
    """[H, W] bool static pixels (or None) and why; paths: frame id -> stage 01's frame."""
    if not config.static_occluders:
        return None, "off (03_masks.static_occluders)"
    if inputs.camera_motion != "static":
        return None, "not available: the camera moves"
    std = temporal_std(read_rgb(paths[f]) for f in progress(sorted(inputs.cameras), desc="03_masks static scene",
                                                          unit="frame", leave=False))
    return std < config.static_max_std, f"temporal colour std < {config.static_max_std} over {len(inputs.cameras)} frames"


def _posed(model: BodyModel, params: BodyParams, row: int) -> tuple[np.ndarray, np.ndarray]:
    """(vertices [V, 3], joints [24, 3]) of one frame, world frame."""
    with torch.no_grad():
        out = model(torch.as_tensor(params.betas)[None], torch.as_tensor(params.global_orient[row:row + 1]),
                    torch.as_tensor(params.body_pose[row:row + 1]), torch.as_tensor(params.transl[row:row + 1]),
                    scale=params.scale)
    return out.vertices[0].numpy(), out.joints[0].numpy()


def _pixels(metres: float, camera: PinholeCamera, layers: BodyLayers, scales: np.ndarray) -> np.ndarray:
    """[N] a length in metres at each person, in pixels at its pelvis depth (0 for a pelvis at or
    behind the camera, whose body has no pixels to grow)."""
    focal = 0.5 * (camera.K[0, 0] + camera.K[1, 1])
    depth = layers.pelvis_depth
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(depth > MIN_PELVIS_DEPTH, focal * metres * scales / depth, 0.0)


class _Frames:
    """Each frame's posed bodies and their layers (people present in that frame, in pid order)."""

    def __init__(self, inputs: MasksInputs):
        self.inputs, self.pids = inputs, sorted(inputs.scene.humans)
        self.faces = inputs.models.faces.numpy()
        self.rows = {pid: {int(f): i for i, f in enumerate(inputs.bodies[pid].frame_ids)} for pid in self.pids}

    def layers(self, fid: int) -> tuple[list[str], BodyLayers, np.ndarray, list[np.ndarray]]:
        """(people present, their layers, their scales, their joints [24, 3] world) in frame ``fid``."""
        present = [pid for pid in self.pids if fid in self.rows[pid]]
        posed = [_posed(self.inputs.models[pid], self.inputs.bodies[pid], self.rows[pid][fid]) for pid in present]
        scene = self.inputs.scene
        layers = body_layers([v for v, _ in posed], [j[0] for _, j in posed], self.faces, self.inputs.cameras[fid],
                             scene.width, scene.height)
        return present, layers, np.array([self.inputs.bodies[pid].scale for pid in present]), [j for _, j in posed]


def sam_masks(sam: SamOnnx, image: np.ndarray, layers: BodyLayers, joints: list[np.ndarray],
              camera: PinholeCamera) -> np.ndarray:
    """[N, H, W] Segment Anything masks of the people present, nearest first (GTU's procedure): each
    prompted with its projected joints where its body is the nearest, minus what nearer people took."""
    height, width = layers.owner.shape
    visible = np.zeros((len(joints), height, width), bool)
    if not joints:
        return visible
    embedded = sam.embed(image)
    taken = np.zeros((height, width), bool)
    for p in np.argsort(layers.pelvis_depth, kind="stable"):
        pixels, depth = camera.project(joints[p])
        u, v = np.round(pixels[:, 0]).astype(int), np.round(pixels[:, 1]).astype(int)
        inside = (depth > 0) & (u >= 0) & (u < width) & (v >= 0) & (v < height)
        seen = inside.copy()
        seen[inside] = layers.owner[v[inside], u[inside]] == p
        if seen.any():
            visible[p] = sam.segment(embedded, pixels[seen], np.ones(int(seen.sum()))) & ~taken
            taken |= visible[p]
    return visible


def choose_refine(inputs: MasksInputs, config: MasksConfig) -> str:
    if config.refine == "plate" and inputs.camera_motion != "static":
        raise GlimpseError("03_masks.refine=plate needs a static camera (stage 01 found it moving); use auto, "
                           "grabcut or none")
    if config.refine == "auto":
        return "plate" if inputs.camera_motion == "static" else "none"
    return config.refine


def body_mode_masks(config: MasksConfig, refine_kind: str, layers: BodyLayers, camera: PinholeCamera,
                    scales: np.ndarray, static_evidence: tuple[np.ndarray, list[np.ndarray]] | None,
                    image: np.ndarray | None, plate: Plate | None) -> FrameMasks:
    """One frame in body mode. static_evidence: (static pixels [H, W], per present person where its
    body surface moves [H, W]) for a static camera; image [H, W, 3] for GrabCut or the plate."""
    dilate = _pixels(config.dilate_m, camera, layers, scales)
    erode = _pixels(config.static_erode_m, camera, layers, scales)
    reach = _pixels(config.static_reach_m, camera, layers, scales)
    in_front = near = None
    if static_evidence is not None and len(layers.pelvis_depth):
        static, moving = static_evidence
        # static colour means scene (not person) only where the body there, or next to it, moves; it is
        # trusted in the body's interior, and from there reaches the thin parts (feet) the erosion drops
        in_front = np.stack([static_in_front(full, static & moving[k], erode[k], reach[k])
                             for k, full in enumerate(layers.full)])
        near = np.stack([static & disk(moving[k] & full, dilate[k]) for k, full in enumerate(layers.full)])
    refine = None
    if refine_kind == "grabcut":
        band = _pixels(config.grabcut_band_m, camera, layers, scales)
        refine = lambda k, region, sure, forbidden: grabcut_region(  # noqa: E731
            image, region, sure, forbidden, band[k], config.grabcut_iterations)
    elif refine_kind == "plate":
        refine = plate_refiner(layers, plate.foreground(image, config.plate_threshold), plate.known,
                               _pixels(config.plate_band_m, camera, layers, scales),
                               _pixels(config.plate_core_m, camera, layers, scales),
                               None if static_evidence is None else static_evidence[0])
    return body_frame_masks(layers, dilate, _pixels(config.occluder_dilate_m, camera, layers, scales), in_front,
                            near, refine)


def static_pass(frames: _Frames, config: MasksConfig, paths: dict[int, Path], motion_wanted: bool,
                plate_wanted: bool) -> tuple[SurfaceMotion | None, Plate | None]:
    """First pass over the frames (static camera): how the body surface under each pixel moves, per
    person, and the background plate from the frames' pixels no grown body covers."""
    scene, template = frames.inputs.scene, frames.inputs.models.default.v_template.numpy()  # canonical face places
    motion = SurfaceMotion(frames.pids, scene.height, scene.width, template[frames.faces].mean(1)) \
        if motion_wanted else None
    ids = sorted(frames.inputs.cameras)
    picks = np.unique(np.linspace(0, len(ids) - 1, min(config.plate_frames, len(ids))).round().astype(int))
    plate_ids = {ids[k] for k in picks} if plate_wanted else set()
    images, covered = [], []
    for fid in progress(ids, desc="03_masks static pass", unit="frame", leave=False):
        present, layers, scales, _ = frames.layers(fid)
        if motion is not None:
            for k, pid in enumerate(present):
                motion.add(pid, layers.faces[k])
        if fid in plate_ids:
            margin = _pixels(config.plate_margin_m, frames.inputs.cameras[fid], layers, scales)
            images.append(read_rgb(paths[fid]))
            grown = [disk(full, margin[k]) for k, full in enumerate(layers.full)]
            covered.append(np.any(grown, axis=0) if grown else np.zeros((scene.height, scene.width), bool))
    return motion, (median_plate(images, covered) if plate_wanted else None)


def compute_masks(inputs: MasksInputs, config: MasksConfig, out: Path) -> dict:
    """Write masks/, occluders/ under ``out``; return the masks.json document."""
    mode = choose_mode(inputs, config)
    scene, frames = inputs.scene, _Frames(inputs)
    pids = frames.pids
    paths = frame_files(inputs.frames_dir)
    static, static_note = static_scene(inputs, config, paths) if mode == "body" \
        else (None, "not needed (provided or Segment Anything masks)")
    refine_kind = choose_refine(inputs, config) if mode == "body" else "none"
    moving = plate = None
    if static is not None or refine_kind == "plate":
        motion, plate = static_pass(frames, config, paths, static is not None, refine_kind == "plate")
        if motion is not None:
            moving = {pid: motion.moving(pid, config.static_motion_min_m) for pid in pids}
    undistorter = scene_undistorter(scene)

    def scene_mask(pid: str, fid: int) -> np.ndarray:
        return undistorter.mask(read_mask(scene.humans[pid].masks[fid]))

    sam = SamOnnx(config.sam_encoder_path, config.sam_decoder_path) if mode == "onnx-sam" else None
    frames_doc: dict[str, dict] = {}
    overlaps: dict[str, list[float]] = {pid: [] for pid in pids}
    can_score = mode != "provided" and all(person.masks for person in scene.humans.values())
    for fid in progress(sorted(inputs.cameras), desc="03_masks", unit="frame"):
        camera = inputs.cameras[fid]
        present, layers, scales, joints = frames.layers(fid)
        erode = _pixels(config.static_erode_m, camera, layers, scales)
        reach = _pixels(config.static_reach_m, camera, layers, scales)
        occluder = _pixels(config.occluder_dilate_m, camera, layers, scales)
        if mode == "provided":
            given = np.stack([scene_mask(pid, fid) for pid in present]) if present \
                else np.zeros((0, scene.height, scene.width), bool)
            masks = provided_frame_masks(layers, given, erode, reach, occluder)
        elif mode == "onnx-sam":
            image = read_rgb(paths[fid])
            masks = provided_frame_masks(layers, sam_masks(sam, image, layers, joints, camera), erode, reach,
                                         occluder)
        else:
            image = read_rgb(paths[fid]) if refine_kind != "none" else None
            static_evidence = None if moving is None else (static, [moving[pid] for pid in present])
            masks = body_mode_masks(config, refine_kind, layers, camera, scales, static_evidence, image, plate)
        _write_frame(out, fid, pids, present, masks, scene.height, scene.width)
        frames_doc[frame_name(fid)] = {
            "depth_order": [present[k] for k in masks.order],
            "pelvis_depth": {present[k]: float(layers.pelvis_depth[k]) for k in masks.order},
            "visible_pixels": {present[k]: int(masks.visible[k].sum()) for k in masks.order}}
        if can_score:
            for k, pid in enumerate(present):
                if fid in scene.humans[pid].masks:
                    truth = scene_mask(pid, fid)
                    union = (truth | masks.visible[k]).sum()
                    if union:
                        overlaps[pid].append(float((truth & masks.visible[k]).sum() / union))
    doc = {"format": MASKS_FORMAT, "mode": mode, "refine": refine_kind, "people": pids, "static_scene": static_note,
           "frames": frames_doc}
    if can_score:
        doc["iou_vs_scene_masks"] = {pid: (float(np.mean(v)) if v else None) for pid, v in overlaps.items()}
    return doc


def _write_frame(out: Path, fid: int, pids: list[str], present: list[str], masks: FrameMasks, height: int,
                 width: int) -> None:
    name = f"{frame_name(fid)}.png"
    empty = np.zeros((height, width), bool)
    for pid in pids:
        k = present.index(pid) if pid in present else None
        write_png(out / "masks" / pid / name, masks.visible[k] if k is not None else empty)
        write_png(out / "occluders" / pid / name, masks.occluders[k] if k is not None else empty)
    write_png(out / "masks" / "union" / name, masks.visible.any(0) if len(present) else empty)
