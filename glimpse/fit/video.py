"""Stage 02's overlay video: every fitted body over the frames stage 01 wrote (glimpse.fit.overlay)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from glimpse.body.models import BodyModels
from glimpse.cameras.model import PinholeCamera
from glimpse.fit.overlay import PERSON_COLOURS, OverlayBody, overlay_frame
from glimpse.io.images import frame_files, read_rgb
from glimpse.io.progress import progress
from glimpse.io.video import write_mp4
from glimpse.scene import Scene


def write_overlay_video(path: Path, scene: Scene, models: BodyModels, cameras: dict[int, PinholeCamera], fits: list,
                        frames_dir: Path, keypoints: dict[str, tuple[np.ndarray, np.ndarray]]) -> int:
    """One video frame per frame with a camera: the fitted bodies (fits: glimpse.fit.stage.PersonFit) and
    each person's confident observed 2D keypoints (pid -> (frame_ids [T], [T, K, 3] x, y, confidence)).
    frames_dir: stage 01's frames/. Returns the number of frames written."""
    images = frame_files(frames_dir)
    faces = models.faces.numpy()
    rows = {fit.pid: {int(f): i for i, f in enumerate(fit.params.frame_ids)} for fit in fits}

    def frames():
        for fid in progress(sorted(cameras), desc="02_smpl_fit overlay", unit="frame", leave=False):
            bodies = []
            for k, fit in enumerate(fits):
                row = rows[fit.pid].get(fid)
                if row is None:
                    continue
                p = fit.params
                with torch.no_grad():
                    vertices = models[fit.pid](
                        torch.as_tensor(p.betas)[None], torch.as_tensor(p.global_orient[row:row + 1]),
                        torch.as_tensor(p.body_pose[row:row + 1]), torch.as_tensor(p.transl[row:row + 1]),
                        scale=p.scale).vertices[0].numpy()
                points, confidence = None, None
                if fit.pid in keypoints:
                    ids, values = keypoints[fit.pid]
                    hit = np.nonzero(ids == fid)[0]
                    if len(hit):
                        points, confidence = values[hit[0], :, :2], values[hit[0], :, 2]
                bodies.append(OverlayBody(vertices, points, confidence, PERSON_COLOURS[k % len(PERSON_COLOURS)]))
            yield overlay_frame(read_rgb(images[fid]), cameras[fid], faces, bodies)

    return write_mp4(path, frames(), scene.fps)
