"""How well body parameters explain a person's keypoints: per frame, the mean distance between
the body's keypoints and the observed ones with enough confidence (3D in world units, 2D in
pixels through stage 01's cameras)."""

from __future__ import annotations

import numpy as np
import torch

from glimpse.body.keypoints import keypoint_map
from glimpse.body.model import BodyModel
from glimpse.body.params import BodyParams
from glimpse.cameras.model import PinholeCamera


def body_keypoints(model: BodyModel, params: BodyParams, layout: str) -> np.ndarray:
    """[T, J, 3] the body's keypoints in the world for every frame of ``params``."""
    kmap = keypoint_map(layout, model.data)
    with torch.no_grad():
        out = model(torch.as_tensor(params.betas)[None], torch.as_tensor(params.global_orient),
                    torch.as_tensor(params.body_pose), torch.as_tensor(params.transl),
                    scale=torch.full((len(params.frame_ids),), params.scale, dtype=model.dtype))
        return kmap(out.joints, out.vertices).numpy()


def residuals_3d(predicted: dict[int, np.ndarray], frame_ids: np.ndarray, joints: np.ndarray,
                 min_confidence: float) -> dict[int, float]:
    """Mean distance (world units) per frame over keypoints with confidence >= min_confidence.
    predicted: frame id -> [J, 3]; joints [T, J, 4] observed (x, y, z, confidence)."""
    result = {}
    for fid, obs in zip(frame_ids.tolist(), joints):
        keep = obs[:, 3] >= min_confidence
        if fid in predicted and keep.any():
            result[fid] = float(np.linalg.norm(predicted[fid][keep] - obs[keep, :3], axis=1).mean())
    return result


def residuals_2d(predicted: dict[int, np.ndarray], frame_ids: np.ndarray, keypoints: np.ndarray,
                 cameras: dict[int, PinholeCamera], min_confidence: float) -> dict[int, float]:
    """Mean pixel distance per frame between projected body keypoints and observed [T, J, 3] (x, y, conf)."""
    result = {}
    for fid, obs in zip(frame_ids.tolist(), keypoints):
        keep = obs[:, 2] >= min_confidence
        if fid not in predicted or fid not in cameras or not keep.any():
            continue
        pixels, _ = cameras[fid].project(predicted[fid])
        result[fid] = float(np.linalg.norm(pixels[keep] - obs[keep, :2], axis=1).mean())
    return result


def summary(values: dict[int, float]) -> dict[str, float] | None:
    if not values:
        return None
    array = np.array(list(values.values()))
    return {"mean": float(array.mean()), "median": float(np.median(array)), "max": float(array.max()),
            "frames": len(array)}
