"""H.264 MP4 videos through imageio-ffmpeg (its bundled ffmpeg binary is GPL and runs as a
separate process; docs/licences.md).

Frames are RGB uint8 [H, W, 3]. H.264 with yuv420p needs even sizes: odd frames are padded by
one black row or column at the bottom or right (never scaled, so pixels keep their place).
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

VIDEO_CODEC = "libx264"
VIDEO_QUALITY = 8  # imageio-ffmpeg's 0-10 scale (10 = best); 8 keeps keypoint dots and edges crisp


def even_padded(frame: np.ndarray) -> np.ndarray:
    """[H, W, 3] uint8 -> the same frame padded with black to even height and width."""
    height, width = frame.shape[:2]
    return np.pad(frame, ((0, height % 2), (0, width % 2), (0, 0)))


def write_mp4(path: str | Path, frames: Iterable[np.ndarray], fps: float) -> int:
    """Write ``frames`` (all the same size) to ``path`` as H.264; returns the number written.
    The file appears complete or not at all (written beside it, then renamed)."""
    import imageio_ffmpeg

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(path.name + ".partial.mp4")
    writer, count, size = None, 0, None
    try:
        for frame in frames:
            frame = even_padded(np.ascontiguousarray(frame, dtype=np.uint8))
            if writer is None:
                size = frame.shape[:2]
                writer = imageio_ffmpeg.write_frames(str(partial), (size[1], size[0]), fps=fps, codec=VIDEO_CODEC,
                                                     quality=VIDEO_QUALITY, macro_block_size=1)
                writer.send(None)
            if frame.shape[:2] != size:
                raise ValueError(f"write_mp4 {path}: frame {count} is {frame.shape[:2]}, the first was {size}")
            writer.send(frame)
            count += 1
    finally:
        if writer is not None:
            writer.close()
    if count == 0:
        raise ValueError(f"write_mp4 {path}: no frames")
    partial.replace(path)
    return count


def read_mp4(path: str | Path) -> np.ndarray:
    """[N, H, W, 3] uint8 frames of a video (for tests and tools)."""
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    width, height = meta["size"]
    return np.stack([np.frombuffer(f, np.uint8).reshape(height, width, 3) for f in reader])
