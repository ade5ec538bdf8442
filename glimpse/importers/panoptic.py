"""CMU Panoptic Studio (HD cameras, 3D body keypoints) as a glimpse-scene/1 folder: one HD camera as the input
video, others as held-out views, every person's 3D keypoints in the "coco19" layout (docs/datasets.md).

The source, one sequence folder (``160422_ultimatum1/``; read from the panoptic-toolbox's scripts and README):

    calibration_<seq>.json   {"cameras": [{"name": "00_16", "type": "hd", "panel": 0, "node": 16, "K": 3x3,
                             "distCoef": [k1 k2 p1 p2 k3], "R": 3x3, "t": 3x1 centimetres}, ...]},
                             world to camera (x_cam = R x + t), world up -y
    hdImgs/00_16/00_16_00000042.jpg         HD frames, numbered from 0 (or hdVideos/hd_00_16.mp4, decoded)
    hdPose3d_stage1_coco19/body3DScene_00000042.json
                             {"bodies": [{"id": 3, "joints19": 19 x [x, y, z, confidence] flat, centimetres}]}
                             (a file per HD frame where bodies were reconstructed; ids are kept over time)

There are no body-model fits and no masks: stage 02 fits every person to their 3D keypoints, stage 03 makes
the masks, and the held-out views are scored on the full frame (GTU's humans-only numbers used SAM masks of
the held-out views, which the dataset does not ship).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from glimpse.errors import GlimpseError
from glimpse.importers.common import HeldOutCamera, ImportOptions, numbered_frames
from glimpse.io.images import read_rgb
from glimpse.io.progress import progress
from glimpse.io.video import iter_video_frames
from glimpse.scene.model import CameraPose
from glimpse.scene.writer import SceneWriter

DATASET = "panoptic"
CENTIMETRES_PER_METRE = 100.0
HD_FPS = 29.97  # the HD cameras' rate (fpsType hd_29_97)
JOINTS = 19
# GTU's choice on 160422_ultimatum1: HD camera 16 as input (away from the dome's entrance), 7 held out
DEFAULT_CAMERAS = ("16", "0", "3", "5", "8", "22", "24", "25")
POSE_FOLDER = "hdPose3d_stage1_coco19"


def hd_name(camera: str) -> str:
    """``16`` or ``00_16`` -> ``00_16`` (HD cameras are panel 0)."""
    return camera if "_" in camera else f"00_{int(camera):02d}"


def read_calibration(folder: Path) -> dict[str, dict[str, np.ndarray]]:
    """HD camera name -> K [3, 3], dist [5], R [3, 3], t [3] metres."""
    files = sorted(folder.glob("calibration_*.json"))
    if not files:
        raise GlimpseError(f"{folder}: no calibration_<sequence>.json; give a Panoptic sequence folder")
    try:
        cameras = json.loads(files[0].read_text())["cameras"]
        return {c["name"]: {"K": np.asarray(c["K"], float).reshape(3, 3),
                            "dist": np.asarray(c["distCoef"], float).reshape(-1),
                            "R": np.asarray(c["R"], float).reshape(3, 3),
                            "t": np.asarray(c["t"], float).reshape(3) / CENTIMETRES_PER_METRE}
                for c in cameras if c.get("type", "hd") == "hd" and int(c.get("panel", 0)) == 0}
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise GlimpseError(f"{files[0]}: not Panoptic's calibration file (cameras with name, K, distCoef, R, t): "
                           f"{exc}") from None


def read_bodies(folder: Path, frames: list[int]) -> dict[int, dict[int, np.ndarray]]:
    """Body id -> frame -> [19, 4] (x, y, z metres, confidence in [0, 1]) over ``frames``."""
    bodies: dict[int, dict[int, np.ndarray]] = {}
    for frame in frames:
        path = folder / POSE_FOLDER / f"body3DScene_{frame:08d}.json"
        try:
            doc = json.loads(path.read_text())
            for body in doc["bodies"]:
                joints = np.asarray(body["joints19"], float).reshape(JOINTS, 4)
                joints[:, :3] /= CENTIMETRES_PER_METRE
                joints[:, 3] = np.clip(joints[:, 3], 0.0, 1.0)  # -1 marks a joint not reconstructed
                bodies.setdefault(int(body["id"]), {})[frame] = joints
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise GlimpseError(f"{path}: not a Panoptic body file (bodies with id and 19 x 4 joints19): "
                               f"{exc}") from None
    return bodies


def pose_frames(folder: Path) -> list[int]:
    """The HD frames that have a body file, in order."""
    names = (p.stem.removeprefix("body3DScene_") for p in (folder / POSE_FOLDER).glob("body3DScene_*.json"))
    return sorted(int(n) for n in names if n.isdigit())


class HdFrames:
    """The frames of one HD camera: hdImgs/<name>/<name>_<frame:08d>.jpg, else decoded from its video."""

    def __init__(self, folder: Path, name: str):
        self.images = folder / "hdImgs" / name
        self.video = folder / "hdVideos" / f"hd_{name}.mp4"
        if not self.images.is_dir() and not self.video.is_file():
            raise GlimpseError(f"{folder}: camera {name} has neither hdImgs/{name}/ nor hdVideos/hd_{name}.mp4")
        self.name = name

    def frames(self, wanted: list[int]) -> Iterator[tuple[int, np.ndarray]]:
        """(frame, [H, W, 3] uint8) of the ``wanted`` frames in order, one at a time."""
        if not self.images.is_dir():
            yield from iter_video_frames(self.video, set(wanted), f"{DATASET} {self.name}")
            return
        for frame in wanted:
            path = self.images / f"{self.name}_{frame:08d}.jpg"
            if not path.is_file():
                raise GlimpseError(f"{path}: missing (an HD frame of camera {self.name})")
            yield frame, read_rgb(path)


def import_panoptic(source: Path, scene_dir: Path, options: ImportOptions) -> Path:
    """Write the scene; returns its folder."""
    folder = source / options.sequence if options.sequence and not list(source.glob("calibration_*.json")) else source
    calibration = read_calibration(folder)
    names = [hd_name(c) for c in (options.cameras or DEFAULT_CAMERAS)]
    unknown = [n for n in names if n not in calibration]
    if unknown:
        raise GlimpseError(f"--cameras: no HD camera {', '.join(unknown)} in {folder.name}'s calibration "
                           f"(HD cameras: {', '.join(sorted(calibration))})")
    available = pose_frames(folder)
    frames = numbered_frames(available, options.frames)  # --frames counts HD frame numbers
    if not frames:
        raise GlimpseError(f"{folder}: no {POSE_FOLDER}/body3DScene_*.json among the chosen frames "
                           f"({len(available)} HD frames have bodies)")
    bodies = read_bodies(folder, frames)
    if not bodies:
        raise GlimpseError(f"{folder}: nobody in the chosen frames' body files")
    source_name, heldout = names[0], names[1:]
    writer = SceneWriter(scene_dir, name=f"panoptic_{folder.name}", fps=options.fps or HD_FPS,
                         camera_motion="static")
    height = width = 0
    for frame, rgb in progress(HdFrames(folder, source_name).frames(frames), total=len(frames),
                               desc=f"{DATASET} {folder.name} input", unit="frame"):
        writer.frame(frame, rgb)
        height, width = rgb.shape[:2]
    camera = calibration[source_name]
    pose = CameraPose(camera["R"], camera["t"])
    writer.input_cameras(width, height, camera["K"], camera["dist"], poses={f: pose for f in frames})
    for body_id, track in sorted(bodies.items()):
        ids = sorted(track)
        writer.keypoints3d(f"p{body_id}", np.asarray(ids), "coco19", np.stack([track[f] for f in ids]))
    scored = frames[:: max(1, options.eval_every)]
    for name in progress(heldout, desc=f"{DATASET} {folder.name} held-out views", unit="camera"):
        camera = calibration[name]
        held = HeldOutCamera(writer, f"hd_{name}", camera["K"], camera["dist"], camera["R"], camera["t"])
        for frame, distorted in HdFrames(folder, name).frames(scored):
            held.view(frame, distorted)  # no masks: the full frame
    return writer.finish()
