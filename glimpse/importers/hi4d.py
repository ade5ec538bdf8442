"""Hi4D (pairs of people in close interaction, 8 calibrated cameras, SMPL and instance masks) as a
glimpse-scene/1 folder: one camera as the input video, the others as held-out views (docs/datasets.md).

The source, one sequence folder (``pair00/dance00/``; read from Hi4D's dataset notes, its visualisation script
and the viewer that script uses):

    meta.npz                   "start", "end" (frame ids, inclusive), "genders" (one per person), ...
    cameras/rgb_cameras.npz    "ids" (8,), "intrinsics" (8, 3, 3), "extrinsics" (8, 3, 4) world to camera
                               (OpenCV), "dist_coeffs" (8, 5) [k1 k2 p1 p2 k3]
    images/<camera id>/<frame:06d>.jpg
    seg/img_seg_mask/<camera id>/<person 0|1|all>/<frame:06d>.png   each person's visible mask (any non-zero)
    smpl/<frame:06d>.npz       both people: "betas" (2, 10), "global_orient" (2, 3), "body_pose" (2, 69),
                               "transl" (2, 3), posed as smplx does, metres

Each person's SMPL is of their gender: the scene's overrides name each person's model file
(``body.person_model_paths``; the first person's is also ``body.model_path``), so a pair of a man and a
woman runs with SMPL's male and female models. A skew term in K is dropped (as MultiPly does): the scene
format's cameras have none.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from glimpse.errors import GlimpseError
from glimpse.importers.common import HeldOutCamera, ImportOptions, nonzero_mask, numbered_frames, smpl_model_file
from glimpse.io.images import read_rgb
from glimpse.io.numpy_pickle import load_object_npz
from glimpse.io.progress import progress
from glimpse.scene.model import CameraPose
from glimpse.scene.writer import SceneWriter

DATASET = "hi4d"
DEFAULT_FPS = 30.0  # the official viewer's playback rate; the files state none
DEFAULT_INPUT = "76"  # GTU's input camera on pair00-dance and pair01-hug; the other seven are held out
PEOPLE = 2


def sequence_folder(source: Path, sequence: str | None) -> Path:
    """SOURCE when it holds meta.npz, else SOURCE/<sequence> (``pair00/dance00``)."""
    if (source / "meta.npz").is_file():
        return source
    if sequence and (source / sequence / "meta.npz").is_file():
        return source / sequence
    raise GlimpseError(f"{source}: no meta.npz; give a Hi4D sequence folder (pair00/dance00/) or the dataset "
                       "folder with --sequence pair00/dance00")


def read_cameras(folder: Path) -> dict[str, dict[str, np.ndarray]]:
    """Camera id (text) -> K [3, 3] (skew dropped), dist [5], R [3, 3], t [3]."""
    path = folder / "cameras" / "rgb_cameras.npz"
    entries = load_object_npz(path)
    try:
        cameras = {}
        for index, camera_id in enumerate(np.asarray(entries["ids"]).reshape(-1)):
            K = np.asarray(entries["intrinsics"][index], float).reshape(3, 3).copy()
            K[0, 1] = 0.0
            Rt = np.asarray(entries["extrinsics"][index], float).reshape(3, 4)
            dist = np.asarray(entries["dist_coeffs"][index], float).reshape(-1)
            cameras[str(int(camera_id))] = {"K": K, "dist": dist, "R": Rt[:, :3], "t": Rt[:, 3]}
    except (KeyError, IndexError, ValueError, TypeError) as exc:
        raise GlimpseError(f"{path}: not Hi4D's camera file (ids, intrinsics, extrinsics, dist_coeffs): "
                           f"{exc}") from None
    return cameras


def read_bodies(folder: Path, frames: list[int]) -> dict[str, np.ndarray]:
    """betas [2, 10] (the first frame's), global_orient [2, T, 3], body_pose [2, T, 69], transl [2, T, 3]."""
    rows: dict[str, list[np.ndarray]] = {"global_orient": [], "body_pose": [], "transl": []}
    betas = None
    for frame in frames:
        path = folder / "smpl" / f"{frame:06d}.npz"
        entry = load_object_npz(path)
        try:
            betas = np.asarray(entry["betas"], float).reshape(PEOPLE, 10) if betas is None else betas
            for key, width in (("global_orient", 3), ("body_pose", 69), ("transl", 3)):
                rows[key].append(np.asarray(entry[key], float).reshape(PEOPLE, width))
        except (KeyError, ValueError) as exc:
            raise GlimpseError(f"{path}: not a Hi4D SMPL file (betas, global_orient, body_pose, transl of two "
                               f"people): {exc}") from None
    return {"betas": betas, **{key: np.stack(values, axis=1) for key, values in rows.items()}}


def masks_of(folder: Path, camera: str, frame: int) -> list[np.ndarray]:
    """Each person's visible mask [H, W] bool in one camera's frame."""
    masks = []
    for person in range(PEOPLE):
        path = folder / "seg" / "img_seg_mask" / camera / str(person) / f"{frame:06d}.png"
        mask = nonzero_mask(path)
        if mask is None:
            raise GlimpseError(f"{path}: missing (person {person}'s mask)")
        masks.append(mask)
    return masks


def body_model_overrides(model_files: list[Path]) -> dict:
    """The scene's ``body`` overrides: the first person's model as everyone's, then each person whose model
    differs by their own file (pids p0, p1, ... in the order of ``model_files``)."""
    shared = model_files[0]
    own = [f"p{k}={path}" for k, path in enumerate(model_files) if path != shared]
    return {"model_path": str(shared), **({"person_model_paths": own} if own else {})}


def import_hi4d(source: Path, scene_dir: Path, options: ImportOptions) -> Path:
    """Write the scene; returns its folder."""
    folder = sequence_folder(source, options.sequence)
    meta = load_object_npz(folder / "meta.npz")
    try:
        start, end = int(np.asarray(meta["start"]).reshape(-1)[0]), int(np.asarray(meta["end"]).reshape(-1)[0])
        genders = [str(g) for g in np.asarray(meta["genders"]).reshape(-1)]
    except (KeyError, IndexError, ValueError) as exc:
        raise GlimpseError(f"{folder / 'meta.npz'}: no start, end or genders: {exc}") from None
    name = f"{folder.parent.name}_{folder.name}"
    if len(genders) != PEOPLE:
        raise GlimpseError(f"{folder / 'meta.npz'}: genders names {len(genders)} people, Hi4D pairs have {PEOPLE}")
    model_files = [smpl_model_file(options, DATASET, gender, f"{name}'s person {k} ({gender})")
                   for k, gender in enumerate(genders)]
    cameras = read_cameras(folder)
    requested = options.cameras or (DEFAULT_INPUT, *[c for c in sorted(cameras, key=int) if c != DEFAULT_INPUT])
    unknown = [c for c in requested if c not in cameras]
    if unknown:
        raise GlimpseError(f"--cameras: no camera {', '.join(unknown)} in {name} (cameras: "
                           f"{', '.join(sorted(cameras, key=int))})")
    frames = numbered_frames(list(range(start, end + 1)), options.frames)  # --frames counts Hi4D's frame numbers
    if not frames:
        raise GlimpseError(f"--frames selects none of {name}'s frames {start}..{end}")
    bodies = read_bodies(folder, frames)
    writer = SceneWriter(scene_dir, name=f"hi4d_{name}", fps=options.fps or DEFAULT_FPS, camera_motion="static",
                         body_model="smpl", overrides={"body": body_model_overrides(model_files)})
    source_camera, heldout = requested[0], requested[1:]
    width = height = 0
    for frame in progress(frames, desc=f"{DATASET} {name} input", unit="frame"):
        rgb = read_rgb(folder / "images" / source_camera / f"{frame:06d}.jpg")
        height, width = rgb.shape[:2]
        writer.frame(frame, rgb)
        for person, mask in enumerate(masks_of(folder, source_camera, frame)):
            writer.person_mask(f"p{person}", frame, mask)
    camera = cameras[source_camera]
    pose = CameraPose(camera["R"], camera["t"])
    writer.input_cameras(width, height, camera["K"], camera["dist"], poses={f: pose for f in frames})
    for person in range(PEOPLE):
        writer.smpl(f"p{person}", np.asarray(frames), bodies["betas"][person], bodies["global_orient"][person],
                    bodies["body_pose"][person], bodies["transl"][person])
    scored = frames[:: max(1, options.eval_every)]
    for camera_id in progress(heldout, desc=f"{DATASET} {name} held-out views", unit="camera"):
        camera = cameras[camera_id]
        held = HeldOutCamera(writer, f"cam{camera_id}", camera["K"], camera["dist"], camera["R"], camera["t"])
        for frame in scored:
            held.view(frame, read_rgb(folder / "images" / camera_id / f"{frame:06d}.jpg"),
                      {f"p{k}": mask for k, mask in enumerate(masks_of(folder, camera_id, frame))})
    return writer.finish()
