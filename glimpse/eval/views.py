"""The views stage 07 scores: the scene's held-out cameras (``eval/``), or, without them, every
few input frames, each with its ground-truth image and masks."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from glimpse.cameras.model import PinholeCamera
from glimpse.eval.config import EvalConfig
from glimpse.io.images import frame_files, frame_name, read_mask, read_rgb
from glimpse.scene.model import Scene


@dataclass(frozen=True)
class ScoredView:
    """One view to score: ``name`` (camera/frame), the frame id whose poses are rendered, the camera (with
    its image size), the ground truth image and the union human mask (None: a held-out camera without masks,
    scored on the full frame only), and per-person masks where known."""

    name: str
    frame_id: int
    camera: PinholeCamera
    image: Path
    union_mask: Path | None
    person_masks: dict[str, Path]

    def read(self) -> tuple[np.ndarray, np.ndarray | None, dict[str, np.ndarray]]:
        """(image [H, W, 3] uint8, union [H, W] bool or None, pid -> mask [H, W] bool)."""
        union = read_mask(self.union_mask) if self.union_mask is not None else None
        return read_rgb(self.image), union, {pid: read_mask(path) for pid, path in self.person_masks.items()}


@dataclass(frozen=True)
class ViewSet:
    source: str  # "held-out" | "input"
    description: str  # for the protocol
    views: list[ScoredView]


def heldout_views(scene: Scene, world_is_scene_frame: bool) -> list[ScoredView]:
    """Every image of every eval/ camera (its per-frame pose where given)."""
    if not world_is_scene_frame:
        return []
    views = []
    for name, cam in sorted(scene.eval_cameras.items()):
        for fid in sorted(cam.images):
            camera = cam.camera_at(fid)
            masks = {pid: frames[fid] for pid, frames in cam.person_masks.items() if fid in frames}
            views.append(ScoredView(f"{name}/{frame_name(fid)}", fid, camera, cam.images[fid],
                                    cam.union_masks.get(fid), masks))
    return views


def input_views(cameras: dict[int, PinholeCamera], frames_dir: Path, masks_dir: Path, pids: list[str],
                every: int) -> list[ScoredView]:
    """Every ``every``-th input frame with a camera, with stage 03's masks as the ground-truth masks."""
    frames = frame_files(frames_dir)
    views = []
    for fid in [f for f in sorted(cameras) if f in frames][::max(every, 1)]:
        name = frame_name(fid)
        masks = {pid: path for pid in pids if (path := masks_dir / pid / f"{name}.png").is_file()}
        views.append(ScoredView(f"input/{name}", fid, cameras[fid], frames[fid],
                                masks_dir / "union" / f"{name}.png", masks))
    return views


def choose_views(config: EvalConfig, scene: Scene, world_is_scene_frame: bool, cameras: dict[int, PinholeCamera],
                 frames_dir: Path, masks_dir: Path) -> ViewSet:
    """Held-out views when the scene has them and ``heldout: auto``, else the input view."""
    held = heldout_views(scene, world_is_scene_frame) if config.heldout == "auto" else []
    if held:
        cams = ", ".join(sorted(scene.eval_cameras))
        unmasked = sorted(name for name, cam in scene.eval_cameras.items() if not cam.union_masks)
        if len(unmasked) == len(scene.eval_cameras):
            masks = "no ground-truth masks: full-frame metrics only"
        elif unmasked:
            masks = f"ground-truth masks from eval/ (none for {', '.join(unmasked)}: scored on the full frame only)"
        else:
            masks = "ground-truth masks from eval/"
        return ViewSet("held-out", f"held-out cameras {cams} (eval/), every frame with a ground-truth image; "
                                   f"{masks}", held)
    why = ("heldout: input" if config.heldout == "input" else
           "the scene has no eval/ cameras" if not scene.eval_cameras else
           "eval/ cameras are in the scene's frame, but stage 01 rebuilt the world by structure from motion")
    views = input_views(cameras, frames_dir, masks_dir, sorted(scene.humans), config.input_view_every)
    return ViewSet("input", f"the INPUT view ({why}): every {config.input_view_every}th input frame, masks from "
                            f"stage 03. These numbers measure the fit to seen frames, not novel views", views)
