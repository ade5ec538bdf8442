"""glimpse-cameras/1 files: the input cameras.json and stage 01's output cameras.json."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from glimpse.cameras.model import PinholeCamera
from glimpse.errors import GlimpseError
from glimpse.io.images import frame_name, parse_frame_name

CAMERAS_FORMAT = "glimpse-cameras/1"


def write_cameras_json(path: Path, width: int, height: int, cameras: dict[int, PinholeCamera]) -> None:
    """Write one camera per frame id. K is written once when shared, else per frame."""
    if not cameras:
        raise ValueError("write_cameras_json needs at least one camera")
    ks = [c.K for c in cameras.values()]
    shared = all(np.allclose(k, ks[0], rtol=0, atol=1e-9) for k in ks)
    frames = {}
    for fid in sorted(cameras):
        cam = cameras[fid]
        entry = {"R": cam.R.tolist(), "t": cam.t.tolist()}
        if not shared:
            entry["K"] = cam.K.tolist()
        frames[frame_name(fid)] = entry
    doc = {"format": CAMERAS_FORMAT, "width": int(width), "height": int(height), "K": ks[0].tolist(), "frames": frames}
    path.write_text(json.dumps(doc, indent=1) + "\n")


def read_cameras_json(path: Path) -> tuple[int, int, dict[int, PinholeCamera]]:
    """Read a stage-01 cameras.json: (width, height, frame id -> camera)."""
    doc = json.loads(Path(path).read_text())
    if doc.get("format") != CAMERAS_FORMAT:
        raise GlimpseError(f"{path}: unknown format {doc.get('format')!r}; this reader knows {CAMERAS_FORMAT}")
    K = np.asarray(doc["K"], dtype=np.float64)
    cameras = {}
    for name, entry in doc.get("frames", {}).items():
        fid = parse_frame_name(name)
        if fid is None:
            raise GlimpseError(f"{path}: frame key {name!r} is not a 6-digit frame id")
        cameras[fid] = PinholeCamera(
            K=np.asarray(entry.get("K", K), dtype=np.float64),
            R=np.asarray(entry["R"], dtype=np.float64),
            t=np.asarray(entry["t"], dtype=np.float64),
            width=int(doc["width"]), height=int(doc["height"]),
        )
    return int(doc["width"]), int(doc["height"]), cameras
