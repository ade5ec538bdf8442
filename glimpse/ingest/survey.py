"""The ingest's first pass over a video: which decoded frames become scene frames, whether the camera moves,
and (for a fixed camera) the background plate.

Frame times follow the container's presentation timestamps, so a variable-frame-rate phone video becomes a
constant-rate scene: scene frame k is the decoded frame on screen at time k / fps (fps: the parameter, else the
container's rate). A constant-rate video keeps its own frame indices as ids, and a part of the video
(``ingest.start_s``, ``ingest.end_s``) keeps the ids the whole video would give: id k is at k / fps. Frames are
streamed: the pass holds only a bounded sample of frames (for the plate and the motion measure, from the part
ingested), at the tracking size; frames nobody needs are decoded but never converted.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import ceil, inf
from pathlib import Path

import cv2
import numpy as np

from glimpse.cameras.motion import MotionMeasure, measure_motion, sample_ids
from glimpse.errors import GlimpseError
from glimpse.ingest.config import IngestConfig
from glimpse.io.progress import progress
from glimpse.io.video import VideoInfo, container_tags, iter_video, probe_video

TIME_TOLERANCE_S = 1e-3  # a frame shown within a millisecond of a grid time counts as on it
TRUNCATED_SHARE = 0.9  # decoding fewer than this share of the frames the container lists means a cut file
FULL_FRAME_DIAGONAL_MM = 43.2666  # a 35 mm film frame's diagonal: what "35 mm equivalent" focal lengths refer to
FOCAL_35MM_TAGS = ("focal_length.35mm_equivalent", "focallengthin35mmformat")  # tag name endings (Apple, EXIF)


@dataclass(frozen=True)
class Survey:
    info: VideoInfo
    width: int  # the scene's frame size, pixels (ingest.max_side)
    height: int
    track_width: int  # the size people are found and followed at (ingest.track_max_side)
    track_height: int
    fps: float  # the scene's frame rate
    chosen: dict[int, int]  # decode index -> scene frame id
    decoded: int  # frames decoded in the first pass (those before ingest.start_s included)
    truncated: bool  # the container promised more frames than decoded (and no frame limit explains it)
    limited: bool  # ingest.max_frames cut the video short
    motion: MotionMeasure
    static: bool  # the measured motion is within ingest.motion_threshold
    focal_35mm: float | None  # the container's 35 mm equivalent focal length (millimetres), when it gives one
    plate: np.ndarray | None  # [H, W, 3] uint8 per-pixel median of sampled frames (fixed camera), else None


def first_grid_id(start_s: float, fps: float) -> int:
    """The scene frame id of the first grid time at or after ``start_s`` (seconds from the video's first frame)."""
    return max(0, ceil((start_s - TIME_TOLERANCE_S) * fps))


def grid_choice(times: list[float], fps: float, max_frames: int, start_s: float = 0.0,
                end_s: float | None = None) -> dict[int, int]:
    """Decode index -> scene frame id: for each grid time k / fps (time measured from the first frame; k from the
    first grid time at or after ``start_s`` to the last at or before ``end_s``, None: the last frame; at most
    ``max_frames`` of them) the last frame shown at or before it. Scene frame id k is the video's time k / fps
    whatever the segment. ``times`` must be increasing."""
    if not times:
        return {}
    origin = times[0]
    last_s = times[-1] - origin if end_s is None else min(end_s, times[-1] - origin)
    chosen: dict[int, int] = {}
    index = 0
    first = first_grid_id(start_s, fps)
    for k in range(first, first + max_frames):
        grid = k / fps
        if grid > last_s + TIME_TOLERANCE_S:
            break
        while index + 1 < len(times) and times[index + 1] - origin <= grid + TIME_TOLERANCE_S:
            index += 1
        chosen.setdefault(index, k)
    return chosen


def focal_from_tags(tags: dict[str, str]) -> float | None:
    """The 35 mm equivalent focal length (mm) a container's tags give, if any."""
    for key, value in tags.items():
        if key.lower().endswith(FOCAL_35MM_TAGS):
            try:
                focal = float(value.split()[0])
            except (ValueError, IndexError):
                continue
            if focal > 0:
                return focal
    return None


def intrinsics_from_focal(focal_35mm: float, width: int, height: int) -> np.ndarray:
    """[3, 3] K for a 35 mm equivalent focal length: focal / 43.27 mm of the image diagonal, square pixels,
    principal point at the image centre (pixel centres at integers)."""
    f = focal_35mm / FULL_FRAME_DIAGONAL_MM * float(np.hypot(width, height))
    return np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])


def fitted_size(info: VideoInfo, max_side: int) -> tuple[int, int]:
    """(width, height) of the video's frames shrunk, if needed, to ``max_side`` (aspect ratio kept)."""
    scale = min(1.0, max_side / max(info.width, info.height))
    return max(1, round(info.width * scale)), max(1, round(info.height * scale))


def _segment(path: Path, config: IngestConfig) -> tuple[float, float | None]:
    """(start, end) of the part of the video to ingest, seconds from its first frame (end None: to the end)."""
    start_s, end_s = config.start_s, config.end_s
    if not start_s >= 0:
        raise GlimpseError(f"{path}: ingest.start_s must be 0 or more seconds, got {start_s}")
    if end_s is not None and not end_s > start_s:
        raise GlimpseError(f"{path}: ingest.end_s ({end_s} s) must come after ingest.start_s ({start_s} s)")
    return start_s, end_s


def survey_video(path: Path, config: IngestConfig) -> Survey:
    """First pass (see the module docstring)."""
    info = probe_video(path)
    fps = config.fps or info.fps
    if not fps or fps <= 0:
        raise GlimpseError(f"{path}: the container gives no frame rate; set ingest.fps")
    start_s, end_s = _segment(path, config)
    track_size = fitted_size(info, config.track_max_side)
    last_grid_s = (first_grid_id(start_s, fps) + config.max_frames - 1) / fps  # the frame limit's last grid time
    segment_end_s = inf if end_s is None else end_s
    stop_after_s = min(last_grid_s, segment_end_s) + 1.0 / fps  # no need to decode beyond the last kept grid time
    expected = ceil((stop_after_s - start_s) * (info.fps or fps)) + 1  # frames decoded within the segment
    if info.frame_count > 0:
        expected = min(expected, info.frame_count)
    sample_every = max(1, ceil(expected / config.plate_frames))
    times: list[float] = []
    samples: list[np.ndarray] = []
    in_segment = 0
    cut = False
    for frame in progress(iter_video(path, track_size), desc="surveying video", unit="frame", leave=False,
                          total=info.frame_count or None):
        seconds = frame.seconds
        if times and seconds <= times[-1]:  # a decoder without timestamps: fall back to the nominal rate
            seconds = times[-1] + 1.0 / fps
        if times and seconds - times[0] > stop_after_s:
            cut = True
            break
        times.append(seconds)
        if not start_s - TIME_TOLERANCE_S <= seconds - times[0] <= stop_after_s - 1.0 / fps + TIME_TOLERANCE_S:
            continue  # outside the part kept: decoded for its time, never converted
        if in_segment % sample_every == 0:
            samples.append(frame.rgb())
            if len(samples) > config.plate_frames:
                samples = samples[::2]
                sample_every *= 2
        in_segment += 1
    if not times:
        raise GlimpseError(f"{path}: the video has no decodable frame")
    chosen = grid_choice(times, fps, config.max_frames, start_s, end_s)
    if not chosen or not samples:
        raise GlimpseError(f"{path}: ingest.start_s ({start_s} s) is past the video's end "
                           f"({times[-1] - times[0]:.2f} s)")
    limited = len(chosen) >= config.max_frames or (cut and last_grid_s < segment_end_s)
    truncated = not cut and not limited and info.frame_count > 0 and len(times) < info.frame_count * TRUNCATED_SHARE

    def grey(rgb: np.ndarray) -> np.ndarray:
        return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)

    picks = sample_ids(list(range(len(samples))), config.motion_sample_frames)
    motion = measure_motion(grey(samples[0]), [(i, grey(samples[i])) for i in picks], config.motion_min_tracked_fraction)
    static = motion.motion <= config.motion_threshold
    plate = np.median(np.stack(samples), axis=0).astype(np.uint8) if static and len(samples) > 1 else None
    width, height = fitted_size(info, config.max_side)
    return Survey(info, width, height, *track_size, float(fps), chosen, len(times), truncated, limited, motion,
                  static, focal_from_tags(container_tags(path)), plate)
