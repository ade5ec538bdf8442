"""EMDB (one person filmed by a moving phone, with ground-truth SMPL and camera poses) as a glimpse-scene/1
folder: the video, the phone's per-frame cameras, the person's SMPL bodies (docs/datasets.md).

The source, one sequence folder (``P0/09_outdoor_walk/``; read from EMDB's dataset notes and its official
visualisation and evaluation code):

    images/00000.jpg ...                     the phone's frames, numbered from 0
    P0_09_outdoor_walk_data.pkl              a pickled dict: "gender" (neutral | male | female), "n_frames",
        "good_frames_mask" (N,) bool, "camera": {"intrinsics" (3, 3), "extrinsics" (N, 4, 4) world to camera
        (OpenCV), "width", "height"}, "smpl": {"poses_root" (N, 3), "poses_body" (N, 69), "trans" (N, 3),
        "betas" (10,)} in metres, posed as smplx does (global_orient, body_pose, transl)

No distortion, no masks (stage 03 makes them), no held-out camera: stage 07 scores the input view. The bodies
of frames outside ``good_frames_mask`` (the person hidden or out of view) are left out.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from glimpse.errors import GlimpseError
from glimpse.importers.common import GENDERS, ImportOptions, smpl_model_file
from glimpse.io.images import read_rgb
from glimpse.io.numpy_pickle import load_numpy_pickle
from glimpse.io.progress import progress
from glimpse.scene.model import CameraPose
from glimpse.scene.writer import SceneWriter

DATASET = "emdb"
DEFAULT_FPS = 30.0  # EMDB's phone videos; the pickle states no rate
PID = "p0"


def sequence_folder(source: Path, sequence: str | None) -> Path:
    """The folder holding <subject>_<sequence>_data.pkl: SOURCE, or SOURCE/P0/09_outdoor_walk for
    ``--sequence P0/09_outdoor_walk`` (or P0_09_outdoor_walk)."""
    if list(source.glob("*_data.pkl")):
        return source
    if sequence:
        subject, _, name = sequence.replace("/", "_", 1).partition("_")
        folder = source / subject / name
        if list(folder.glob("*_data.pkl")):
            return folder
    raise GlimpseError(f"{source}: no <subject>_<sequence>_data.pkl; give an EMDB sequence folder "
                       "(P0/09_outdoor_walk/) or the dataset folder with --sequence P0/09_outdoor_walk")


def read_sequence(folder: Path) -> dict:
    """The sequence's pickle (numpy arrays in plain containers only), checked for the keys the import uses."""
    path = sorted(folder.glob("*_data.pkl"))[0]
    try:
        with path.open("rb") as handle:
            data = load_numpy_pickle(handle, str(path))
        count = int(data["n_frames"])
        camera, smpl = data["camera"], data["smpl"]
        shapes = {"good_frames_mask": (np.asarray(data["good_frames_mask"]), (count,)),
                  "extrinsics": (np.asarray(camera["extrinsics"]), (count, 4, 4)),
                  "intrinsics": (np.asarray(camera["intrinsics"]), (3, 3)),
                  "poses_root": (np.asarray(smpl["poses_root"]), (count, 3)),
                  "poses_body": (np.asarray(smpl["poses_body"]), (count, 69)),
                  "trans": (np.asarray(smpl["trans"]), (count, 3)), "betas": (np.asarray(smpl["betas"]), (10,))}
        gender = str(data["gender"])
    except Exception as exc:  # a truncated or foreign pickle raises many kinds of errors
        raise GlimpseError(f"{path}: not an EMDB sequence file: {type(exc).__name__}: {exc}") from None
    wrong = [f"{k} {a.shape} (expected {s})" for k, (a, s) in shapes.items() if a.shape != s]
    if wrong or gender not in GENDERS:
        raise GlimpseError(f"{path}: unexpected contents: {', '.join(wrong) or f'gender {gender!r}'}")
    return {"name": path.name.removesuffix("_data.pkl"), "gender": gender, "count": count,
            **{k: a for k, (a, _) in shapes.items()}}


def import_emdb(source: Path, scene_dir: Path, options: ImportOptions) -> Path:
    """Write the scene; returns its folder."""
    folder = sequence_folder(source, options.sequence)
    data = read_sequence(folder)
    model_file = smpl_model_file(options, DATASET, data["gender"], f"{data['name']}'s person's bodies")
    frames = list(range(data["count"]))[options.frames or slice(None)]
    if not frames:
        raise GlimpseError(f"--frames selects no frame of {data['name']} ({data['count']} frames)")
    writer = SceneWriter(scene_dir, name=f"emdb_{data['name']}", fps=options.fps or DEFAULT_FPS,
                         camera_motion="moving", body_model="smpl", overrides={"body": {"model_path": str(model_file)}})
    width = height = 0
    for frame in progress(frames, desc=f"{DATASET} {data['name']}", unit="frame"):
        path = folder / "images" / f"{frame:05d}.jpg"
        if not path.is_file():
            raise GlimpseError(f"{path}: missing (frame {frame} of {data['count']})")
        rgb = read_rgb(path)
        height, width = rgb.shape[:2]
        writer.frame(frame, rgb)
    extrinsics = data["extrinsics"].astype(np.float64)
    writer.input_cameras(width, height, data["intrinsics"].astype(np.float64),
                         poses={f: CameraPose(extrinsics[f, :3, :3], extrinsics[f, :3, 3]) for f in frames})
    good = np.asarray([f for f in frames if bool(data["good_frames_mask"][f])], dtype=np.int64)
    if len(good) == 0:
        raise GlimpseError(f"{data['name']}: no frame of the chosen span has a valid body (good_frames_mask)")
    writer.smpl(PID, good, data["betas"].astype(np.float64), data["poses_root"][good].astype(np.float64),
                data["poses_body"][good].astype(np.float64), data["trans"][good].astype(np.float64))
    return writer.finish()
