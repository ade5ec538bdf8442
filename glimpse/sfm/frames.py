"""The frames every later stage reads: chosen from frames/ or decoded from
video.mp4, subsampled to a frame rate, undistorted, written to stage 01's
``frames/`` (copies, never links: editing a scene frame must not change a published output)."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np

from glimpse.cameras.undistort import Undistorter
from glimpse.errors import GlimpseError
from glimpse.io.images import frame_name, read_rgb, write_png
from glimpse.io.progress import progress
from glimpse.io.video import iter_video_frames
from glimpse.scene import Scene


def select_frame_ids(frame_ids: list[int], scene_fps: float, fps: float | None, max_frames: int | None) -> list[int]:
    """Keep every k-th frame, k = round(scene_fps / fps) (all when fps is None or >= scene_fps),
    then the first ``max_frames``. Ids are kept as they are (the video's own indices)."""
    if fps is not None and fps <= 0:
        raise GlimpseError(f"01_sfm.fps must be positive or null, found {fps}")
    if max_frames is not None and max_frames < 1:
        raise GlimpseError(f"01_sfm.max_frames must be >= 1 or null, found {max_frames}")
    stride = 1 if fps is None else max(1, int(round(scene_fps / fps)))
    chosen = sorted(frame_ids)[::stride]
    return chosen if max_frames is None else chosen[:max_frames]


def write_frames(scene: Scene, frame_ids: list[int], undistorter: Undistorter, out_dir: Path) -> dict[int, Path]:
    """Materialise the chosen frames in ``out_dir`` as ``<id>.png`` (or the input's own
    file, copied, when it needs no undistortion). Returns frame id -> path."""
    out_dir.mkdir(parents=True, exist_ok=True)
    written: dict[int, Path] = {}
    if scene.video_path is not None:
        for index, rgb in iter_video_frames(scene.video_path, set(frame_ids), "decoding video"):
            path = out_dir / f"{frame_name(index)}.png"
            write_png(path, undistorter.image(rgb))
            written[index] = path
        return written
    for fid in progress(frame_ids, desc="frames", unit="frame", leave=False):
        src = scene.frame_paths[fid]
        if undistorter.active:
            path = out_dir / f"{frame_name(fid)}.png"
            write_png(path, undistorter.image(read_rgb(src)))
        else:
            path = out_dir / f"{frame_name(fid)}{src.suffix.lower()}"
            shutil.copyfile(src, path)  # the kernel may share the blocks (copy_file_range), never the file
        written[fid] = path
    return written


def grey(path: Path) -> np.ndarray:
    """An image as (H, W) uint8 grey."""
    return cv2.cvtColor(read_rgb(path), cv2.COLOR_RGB2GRAY)
