"""Videos. Writing: H.264 MP4 through imageio-ffmpeg (its bundled ffmpeg binary is GPL and runs as a
separate process; docs/licences.md). Reading: OpenCV's FFmpeg backend (LGPL libraries in OpenCV's wheel), which
applies the container's display rotation and reports each frame's presentation time.

Frames are RGB uint8 [H, W, 3]. H.264 with yuv420p needs even sizes: odd frames are padded by
one black row or column at the bottom or right (never scaled, so pixels keep their place).
"""

from __future__ import annotations

from collections.abc import Collection, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from glimpse.errors import GlimpseError
from glimpse.io.progress import progress

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


@dataclass(frozen=True)
class VideoInfo:
    """What the container says about a video (sizes after its display rotation)."""

    path: Path
    width: int
    height: int
    frame_count: int  # the container's count (may be an estimate; decoding decides)
    fps: float  # the container's nominal rate
    rotation_deg: float  # the display rotation OpenCV applied (0, 90, 180, 270)


def _open_capture(path: Path) -> cv2.VideoCapture:
    if not path.is_file():
        raise GlimpseError(f"{path}: no such video file")
    capture = cv2.VideoCapture(str(path))
    if not capture.isOpened():
        capture.release()
        raise GlimpseError(f"{path}: not a readable video (not a video file, an unsupported codec, or a file "
                           "truncated before its index); re-encode it, e.g. ffmpeg -i IN -c:v libx264 OUT.mp4")
    capture.set(cv2.CAP_PROP_ORIENTATION_AUTO, 1)
    return capture


def probe_video(path: str | Path) -> VideoInfo:
    """The container's facts about ``path``; GlimpseError when it cannot be read as a video."""
    path = Path(path)
    capture = _open_capture(path)
    try:
        ok, bgr = capture.read()
        if not ok:
            raise GlimpseError(f"{path}: the video has no decodable frame")
        return VideoInfo(path, bgr.shape[1], bgr.shape[0], int(max(capture.get(cv2.CAP_PROP_FRAME_COUNT), 0)),
                         float(capture.get(cv2.CAP_PROP_FPS) or 0.0),
                         float(capture.get(cv2.CAP_PROP_ORIENTATION_META) or 0.0))
    finally:
        capture.release()


def resized(rgb: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``rgb`` [H, W, C] resized to ``size`` (width, height) with the area filter; itself when already that size."""
    if (rgb.shape[1], rgb.shape[0]) == tuple(size):
        return rgb
    return cv2.resize(rgb, tuple(size), interpolation=cv2.INTER_AREA)


@dataclass
class DecodedFrame:
    """One frame of :func:`iter_video`: its decode index and presentation time (seconds), its pixels on request
    (:meth:`rgb`, only while the iteration is at this frame: a frame nobody asks for is never converted)."""

    index: int
    seconds: float
    _capture: cv2.VideoCapture
    _size: tuple[int, int] | None
    _path: Path

    def rgb(self) -> np.ndarray:
        """[H, W, 3] uint8 RGB, display rotation applied, resized to the iteration's size (area filter)."""
        ok, bgr = self._capture.retrieve()
        if not ok:
            raise GlimpseError(f"{self._path}: frame {self.index} could not be read back from the decoder")
        if self._size is not None:
            bgr = resized(bgr, self._size)
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def iter_video(path: str | Path, size: tuple[int, int] | None = None) -> Iterator[DecodedFrame]:
    """Decode ``path`` frame by frame (streaming: one frame in memory at a time). Yields each frame's
    :class:`DecodedFrame`; its pixels (resized to ``size``, (width, height), when given) are made only when asked
    for, before the iteration moves on."""
    path = Path(path)
    capture = _open_capture(path)
    try:
        index = 0
        while capture.grab():
            yield DecodedFrame(index, capture.get(cv2.CAP_PROP_POS_MSEC) / 1000.0, capture, size, path)
            index += 1
    finally:
        capture.release()


def iter_video_frames(path: str | Path, wanted: Collection[int], desc: str) -> Iterator[tuple[int, np.ndarray]]:
    """(decode index, [H, W, 3] uint8 RGB) of the ``wanted`` decode indices of ``path``, in order, with a progress
    bar; the frames between are decoded but not converted, and decoding stops after the last one. Raises
    GlimpseError when the video ends before it."""
    last, decoded = max(wanted), 0
    for frame in progress(iter_video(path), desc=desc, unit="frame", leave=False, total=last + 1):
        decoded = frame.index + 1
        if frame.index in wanted:
            yield frame.index, frame.rgb()
        if frame.index >= last:
            return
    raise GlimpseError(f"{path}: the video ended at frame {decoded}, expected {last + 1} frames")


def container_tags(path: str | Path) -> dict[str, str]:
    """The container's and streams' metadata tags (``key: value``), as the bundled ffmpeg prints them (OpenCV does
    not expose them); empty when ffmpeg is unavailable. Later tags of the same key win."""
    import subprocess

    try:
        import imageio_ffmpeg

        printed = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i", str(path)],
                                 capture_output=True, text=True, errors="replace", timeout=60, check=False).stderr
    except (ImportError, RuntimeError, OSError, subprocess.TimeoutExpired):
        return {}
    tags: dict[str, str] = {}
    depth = None
    for line in printed.splitlines():
        indent = len(line) - len(line.lstrip())
        if line.strip() == "Metadata:":
            depth = indent
            continue
        if depth is not None and indent > depth and ":" in line:
            key, value = line.split(":", 1)
            tags[key.strip()] = value.strip()
        else:
            depth = None
    return tags
