"""How close fitted bodies are to known ones (fixtures' ground truth): mean per-joint position
error over the 24 body joints of the fitted (not interpolated) frames, three ways:

- ``mpjpe_m``: in the world frame as fitted;
- ``sequence_aligned_m``: after one similarity (rotation, translation, scale) over the whole
  sequence, the "global alignment" that removes a 2D fit's depth/size ambiguity;
- ``frame_aligned_m``: after a similarity per frame (PA-MPJPE, as HMR papers report).
"""

from __future__ import annotations

import numpy as np
import torch

from glimpse.body.model import BodyModel
from glimpse.body.params import BodyParams
from glimpse.cameras.align import umeyama


def body_joints(model: BodyModel, betas: np.ndarray, global_orient: np.ndarray, body_pose: np.ndarray,
                transl: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """[T, 24, 3] posed joints."""
    with torch.no_grad():
        out = model(torch.as_tensor(betas)[None], torch.as_tensor(global_orient), torch.as_tensor(body_pose),
                    torch.as_tensor(transl), scale=scale)
    return out.joints.numpy()


def joint_errors(model: BodyModel, fitted: BodyParams, truth: dict[str, np.ndarray]) -> dict[str, float]:
    """truth: betas [10] and per-frame global_orient, body_pose, transl indexed by ``truth['frame_ids']``."""
    keep = ~fitted.interpolated
    ids = fitted.frame_ids[keep]
    rows = np.searchsorted(truth["frame_ids"], ids)
    true = body_joints(model, truth["betas"], truth["global_orient"][rows], truth["body_pose"][rows],
                       truth["transl"][rows])
    fit = body_joints(model, fitted.betas, fitted.global_orient[keep], fitted.body_pose[keep], fitted.transl[keep],
                      fitted.scale)
    whole = umeyama(fit.reshape(-1, 3), true.reshape(-1, 3))
    per_frame = [np.linalg.norm(umeyama(f, t).apply(f) - t, axis=1).mean() for f, t in zip(fit, true)]
    return {"frames": int(len(ids)),
            "mpjpe_m": float(np.linalg.norm(fit - true, axis=-1).mean()),
            "sequence_aligned_m": float(np.linalg.norm(whole.apply(fit.reshape(-1, 3)) - true.reshape(-1, 3),
                                                       axis=1).mean()),
            "frame_aligned_m": float(np.mean(per_frame))}
