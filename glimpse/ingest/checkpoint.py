"""The tracking pass's checkpoint: every track's state after some frame, so that an interrupted ingest goes on
from there (``glimpse ingest`` run again with the same video and parameters).

One ``.npz`` of plain arrays (no pickled objects: it is read with ``allow_pickle=False``), written beside its
final name and renamed over it, so a checkpoint on disk is always whole. A ``fingerprint`` of the video file
and the parameters is stored with it; a checkpoint whose fingerprint differs is not used.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import zipfile
from dataclasses import asdict
from pathlib import Path

import numpy as np

from glimpse.ingest.blazepose import PoseLandmarks
from glimpse.ingest.config import SCENE_UNCHANGED_BY, IngestConfig
from glimpse.ingest.crop import Region
from glimpse.ingest.observation import Track

log = logging.getLogger("glimpse")

LANDMARK_ARRAYS = ("points", "visibility", "presence", "world", "segmentation")
# changing these keeps a checkpoint valid: those that leave the scene as it is, and the fit_* ones (they only go into
# scene.yaml)
NOT_TRACKING_PARAMETERS = SCENE_UNCHANGED_BY + ("fit_size_sigma", "fit_keypoint_noise_m", "fit_unseen_limbs_at_rest",
                                                "fit_up_from_torsos")


def fingerprint(video: Path, config: IngestConfig) -> str:
    """What a checkpoint is valid for: the video file (resolved path, size, modification time) and every
    ingest parameter that changes the tracking."""
    stat = Path(video).stat()
    parameters = {k: v for k, v in asdict(config).items() if k not in NOT_TRACKING_PARAMETERS}
    facts = {"video": str(Path(video).resolve()), "size": stat.st_size, "mtime_ns": stat.st_mtime_ns,
             "config": parameters}
    return hashlib.sha256(json.dumps(facts, sort_keys=True, default=str).encode()).hexdigest()


def _region(values: np.ndarray) -> Region:
    return Region(np.asarray(values[:2], float), float(values[2]), float(values[3]))


def _region_values(region: Region) -> np.ndarray:
    return np.array([*region.centre, region.side, region.angle], float)


def _track_arrays(track: Track) -> dict[str, np.ndarray]:
    landmarks = track.landmarks
    arrays = {name: getattr(landmarks, name) for name in LANDMARK_ARRAYS}
    arrays.update(
        score=np.array(landmarks.score), next_region=_region_values(landmarks.next_region),
        region=_region_values(landmarks.region), index=np.array(track.index), look=track.look,
        velocity=track.velocity, missing=np.array(track.missing), frames=np.array(track.frames, np.int64),
        keypoints=np.array(track.keypoints).reshape(-1, 17, 3), relative3d=np.array(track.relative3d).reshape(-1, 17, 4),
        boxes=np.array(track.boxes).reshape(-1, 4), legs_disputed=np.array(track.legs_disputed, float),
        reidentified=np.array(track.reidentified, float).reshape(-1, 2),
        jumps=np.array(track.jumps, np.int64), looked_again=np.array(track.looked_again, np.int64))
    return arrays


def _track_from(arrays: dict[str, np.ndarray]) -> Track:
    landmarks = PoseLandmarks(**{name: arrays[name] for name in LANDMARK_ARRAYS}, score=float(arrays["score"]),
                              next_region=_region(arrays["next_region"]), region=_region(arrays["region"]))
    return Track(int(arrays["index"]), landmarks, arrays["look"], velocity=arrays["velocity"],
                 missing=int(arrays["missing"]), frames=[int(f) for f in arrays["frames"]],
                 keypoints=list(arrays["keypoints"]), relative3d=list(arrays["relative3d"]),
                 boxes=list(arrays["boxes"]), legs_disputed=[float(d) for d in arrays["legs_disputed"]],
                 reidentified=[(int(f), float(d)) for f, d in arrays["reidentified"]],
                 jumps=[int(f) for f in arrays["jumps"]], looked_again=[int(f) for f in arrays["looked_again"]])


def save_checkpoint(path: Path, tracks: list[Track], frames_done: int, key: str) -> None:
    """Write the tracks' state after the first ``frames_done`` chosen frames to ``path`` (atomically)."""
    arrays = {"fingerprint": np.array(key), "frames_done": np.array(frames_done), "track_count": np.array(len(tracks))}
    for k, track in enumerate(tracks):
        arrays.update({f"track{k}/{name}": value for name, value in _track_arrays(track).items()})
    partial = path.with_name(path.name + ".partial.npz")
    np.savez(partial, **arrays)
    os.replace(partial, path)


def load_checkpoint(path: Path, key: str) -> tuple[list[Track], int] | None:
    """(tracks, frames done) from ``path``, or None when there is none, it was made for another video or
    other parameters (``key``: :func:`fingerprint`), or it cannot be read (then the ingest starts afresh)."""
    if not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            if str(data["fingerprint"]) != key:
                return None
            arrays = {name: data[name] for name in data.files}
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as error:
        log.warning("%s: not a readable ingest checkpoint (%s); tracking starts from the first frame", path, error)
        return None
    tracks = []
    for k in range(int(arrays["track_count"])):
        prefix = f"track{k}/"
        tracks.append(_track_from({name[len(prefix):]: v for name, v in arrays.items() if name.startswith(prefix)}))
    return tracks, int(arrays["frames_done"])
