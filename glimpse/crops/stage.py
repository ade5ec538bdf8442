"""Stage 05's crop part: per person, square crops of the frames where it is visible enough, its soft
mask, the OpenPose-18 skeleton of its posed body and a view prompt, written under
``<pid>/crops/`` with ``crops.json`` (glimpse-crops/1). The identity (token embedding and
cross-attention K/V) is trained only for the sds prior (glimpse/prior/sds/person_identity.py);
any other prior skips it.

Frames: those with a camera (stage 01), a body (stage 02) and a visible mask (stage 03) of at
least ``min_mask_px`` pixels; at most ``max_crops``, evenly spaced. The run.py only loads inputs
and records what this returns.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from glimpse.body.keypoints import KeypointMap, keypoint_map
from glimpse.body.model import NUM_JOINTS, BodyModel
from glimpse.body.models import BodyModels
from glimpse.body.params import BodyParams
from glimpse.cameras.model import PinholeCamera
from glimpse.crops.box import (
    CropBox,
    background_colour,
    composite,
    crop_padded,
    resize_square,
    soft_mask,
    square_box,
    to_uint8,
)
from glimpse.crops.config import CropsConfig
from glimpse.io.images import frame_files, frame_name, read_mask, read_rgb, write_png
from glimpse.io.progress import progress
from glimpse.prior import resolve_prior_kind
from glimpse.prior.skeleton import (
    HEAD_JOINT,
    OPENPOSE18_NAMES,
    draw_skeleton,
    hidden_face,
    shown_keypoints,
)
from glimpse.prior.views import VIEWS, facing_azimuth_deg, person_token, view_prompt, view_word

CROPS_FORMAT = "glimpse-crops/1"
KEYPOINT_LAYOUT = "openpose18"
PELVIS_JOINT = 0
PIXEL_DECIMALS = 2  # crops.json: keypoint pixels rounded to 1/100 pixel
ANGLE_DECIMALS = 2  # crops.json: azimuths rounded to 1/100 degree
MASK_LEVELS = 255  # the soft mask is written as 0-255


@dataclass(frozen=True)
class CropsInputs:
    pids: list[str]  # sorted; a person's index here seeds its background colours
    models: BodyModels  # each person's body model
    cameras: dict[int, PinholeCamera]  # stage 01's, per frame id
    bodies: dict[str, BodyParams]  # stage 02's, per person
    frames_dir: Path  # stage 01's frames/
    masks_dir: Path  # stage 03's masks/ (masks/<pid>/<frame>.png)


@dataclass(frozen=True)
class IdentityPlan:
    """What stage 05 does about the identity: prior_kind is prior.kind resolved; identity "trained" (sds)
    or "skipped", and why."""

    prior_kind: str
    identity: str
    reason: str


def identity_plan(kind: str, diffusion_ready: bool = False) -> IdentityPlan:
    """prior.kind -> the identity plan (``auto`` resolved as glimpse.prior does: sds when ``diffusion_ready``)."""
    resolved = resolve_prior_kind(kind, diffusion_ready)
    if resolved == "sds":
        return IdentityPlan(resolved, "trained", "prior.kind is sds: each person's CustomDiffusion identity "
                                                 "is trained on their crops")
    why = f"auto resolves to {resolved}" if kind == "auto" else f"is {kind}"
    return IdentityPlan(resolved, "skipped", f"prior.kind {why}: only the sds prior uses an identity; "
                                             "crops written for later use")


def evenly_spaced(ids: list[int], count: int) -> list[int]:
    """At most ``count`` of ``ids`` (sorted), evenly spaced, first and last included (0 = all)."""
    if count <= 0 or len(ids) <= count:
        return list(ids)
    picks = np.unique(np.linspace(0, len(ids) - 1, count).round().astype(int))
    return [ids[k] for k in picks]


def usable_frames(inputs: CropsInputs, pid: str, min_mask_px: int) -> list[int]:
    """Sorted frame ids with a camera, a frame, a body of ``pid`` and at least min_mask_px pixels (and
    at least one) of its visible mask."""
    frames = frame_files(inputs.frames_dir)
    with_body = {int(f) for f in inputs.bodies[pid].frame_ids}
    usable = []
    for fid in sorted(set(inputs.cameras) & with_body & set(frames)):
        path = inputs.masks_dir / pid / f"{frame_name(fid)}.png"
        if path.is_file() and int(read_mask(path).sum()) >= max(min_mask_px, 1):
            usable.append(fid)
    return usable


def posed_keypoints(model: BodyModel, kmap: KeypointMap, body: BodyParams, rows: list[int]
                    ) -> tuple[np.ndarray, np.ndarray]:
    """(keypoints [B, 18, 3], joints [B, 24, 3]), world frame, of the body's frames ``rows``
    (scale * LBS + transl)."""
    if not rows:
        return np.zeros((0, len(kmap.names), 3)), np.zeros((0, NUM_JOINTS, 3))
    with torch.no_grad():
        out = model(torch.as_tensor(body.betas), torch.as_tensor(body.global_orient[rows]),
                    torch.as_tensor(body.body_pose[rows]), torch.as_tensor(body.transl[rows]), scale=body.scale)
        keypoints = kmap(out.joints, out.vertices)
    return keypoints.double().numpy(), out.joints.double().numpy()


@dataclass(frozen=True)
class Crop:
    """One crop: image [S, S, 3] uint8 over its background colour, mask [S, S] uint8 (0-255),
    skeleton [S, S, 3] uint8, and its crops.json entry."""

    image: np.ndarray
    mask: np.ndarray
    skeleton: np.ndarray
    entry: dict


def make_crop(image: np.ndarray, mask: np.ndarray, box: CropBox, camera: PinholeCamera, keypoints: np.ndarray,
              joints: np.ndarray, global_orient: np.ndarray, colour: np.ndarray, config: CropsConfig,
              pid: str) -> Crop:
    """image [H, W, 3] uint8 and mask [H, W] bool of one frame; keypoints [18, 3] and joints [24, 3]
    (world) and global_orient [3] of the person in it; colour [3] uint8 of the background."""
    size = config.crop_size_px
    alpha = soft_mask(crop_padded(mask, box, False), config.mask_erode_px, config.mask_feather_px)
    over = composite(crop_padded(image, box, 0), alpha, colour)
    pixels, depth = camera.project(keypoints)
    crop_pixels = box.to_crop(pixels, size)
    shown = shown_keypoints(crop_pixels, depth, hidden_face(keypoints, joints[HEAD_JOINT], camera.centre), size)
    azimuth = facing_azimuth_deg(global_orient, joints[PELVIS_JOINT], camera.centre)
    view = view_word(azimuth, config.front_max_deg, config.back_min_deg)
    entry = {
        "box": box.as_list(), "view": view, "azimuth_deg": round(azimuth, ANGLE_DECIMALS),
        "prompt": view_prompt(config.prompt_template, pid, view), "background_rgb": [int(c) for c in colour],
        "keypoints18": [[round(float(u), PIXEL_DECIMALS), round(float(v), PIXEL_DECIMALS), int(s)] if s else
                        [None, None, 0] for (u, v), s in zip(crop_pixels, shown)],
    }
    return Crop(to_uint8(resize_square(over, size, is_mask=False)),
                to_uint8(resize_square(alpha, size, is_mask=True), MASK_LEVELS),
                draw_skeleton(crop_pixels, shown, size, config.skeleton_line_px), entry)


def person_crops(inputs: CropsInputs, config: CropsConfig, seed: int, pid: str, out: Path) -> dict:
    """Write ``out``/images, masks, skeletons for one person; return its crops.json document."""
    body = inputs.bodies[pid]
    usable = usable_frames(inputs, pid, config.min_mask_px)
    chosen = evenly_spaced(usable, config.max_crops)
    row_of = {int(f): k for k, f in enumerate(body.frame_ids)}
    rows = [row_of[fid] for fid in chosen]
    model = inputs.models[pid]
    keypoints, joints = posed_keypoints(model, keypoint_map(KEYPOINT_LAYOUT, model.data), body, rows)
    frames = frame_files(inputs.frames_dir)
    index = inputs.pids.index(pid)
    entries = []
    for k, fid in enumerate(progress(chosen, desc=f"05 crops {pid}", unit="crop", leave=False)):
        name = frame_name(fid)
        mask = read_mask(inputs.masks_dir / pid / f"{name}.png")
        crop = make_crop(read_rgb(frames[fid]), mask, square_box(mask, config.crop_margin), inputs.cameras[fid],
                         keypoints[k], joints[k], body.global_orient[rows[k]], background_colour(seed, index, fid),
                         config, pid)
        for folder, pixels in (("images", crop.image), ("masks", crop.mask), ("skeletons", crop.skeleton)):
            write_png(out / folder / f"{name}.png", pixels)
        entries.append({"frame": fid, "file": f"{name}.png", "mask_pixels": int(mask.sum()),
                        "interpolated": bool(body.interpolated[rows[k]]), **crop.entry})
    return {"format": CROPS_FORMAT, "person": pid, "token": person_token(pid), "crop_size_px": config.crop_size_px,
            "keypoint_layout": KEYPOINT_LAYOUT, "keypoint_names": list(OPENPOSE18_NAMES),
            "usable_frames": len(usable), "crops": entries}


def person_summary(doc: dict, min_mask_px: int) -> dict:
    """The manifest's summary entry of one person's crops.json document."""
    views = [c["view"] for c in doc["crops"]]
    summary = {"crops": len(views), "usable_frames": doc["usable_frames"],
               "views": {view: views.count(view) for view in VIEWS}}
    if not views:
        summary["note"] = (f"no frame shows at least {min_mask_px} pixels of this person "
                           "(05_textual_inversion.min_mask_px)")
    return summary


def write_crops(inputs: CropsInputs, config: CropsConfig, seed: int, out: Path) -> dict[str, dict]:
    """Every person's ``out/<pid>/crops/`` (crops.json even when empty); returns pid -> document."""
    docs = {}
    for pid in progress(inputs.pids, desc="05_textual_inversion", unit="person"):
        folder = out / pid / "crops"
        docs[pid] = person_crops(inputs, config, seed, pid, folder)
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "crops.json").write_text(json.dumps(docs[pid], indent=1) + "\n")
    return docs
