"""ZJU-MoCap (the LightStage captures released with Neural Body; SMPL fits by EasyMocap) as a glimpse-scene/1
folder: one camera as the input video, the others as held-out views (docs/datasets.md).

The source, one sequence folder (``CoreView_377/``; read from Neural Body's and HumanNeRF's loaders):

    annots.npy      a pickled dict: "cams": {"K": C x (3, 3), "D": C x (5, 1) OpenCV [k1 k2 p1 p2 k3],
                    "R": C x (3, 3), "T": C x (3, 1) millimetres}, world to camera (x_cam = R x + T / 1000);
                    "ims": F x {"ims": C image paths relative to the folder}, camera order as in "cams"
    Camera_B1/000000.jpg ...            distorted images (CoreView_313 and 315: "Camera (1)/..._0001_<time>.jpg",
                                        numbered from 1)
    mask/<camera>/<name>.png, mask_cihp/<camera>/<name>.png     the person: any non-zero value (their union)
    new_params/<i>.npy (or params/)     {"poses": (1, 72), "Rh": (1, 3), "Th": (1, 3), "shapes": (1, 10)}

EasyMocap places a body as V = R(Rh) · SMPL(poses, shapes) + Th, turning about the model's origin (its
``poses[:3]`` is zero); the scene format's smpl.npz turns about the pelvis (smplx's convention), so
global_orient = Rh ∘ poses[:3] and transl = Th + R(Rh) j0 - j0, with j0 the shaped rest pelvis (which needs
the SMPL model: ``--body-model``, the neutral one). One person.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from glimpse.errors import GlimpseError
from glimpse.importers.common import (HeldOutCamera, ImportOptions, camera_name, nonzero_mask, pelvis_placed_smpl,
                                      rest_pelvis, smpl_model_file)
from glimpse.io.images import read_rgb
from glimpse.io.numpy_pickle import load_object_npy
from glimpse.io.progress import progress
from glimpse.scene.model import CameraPose
from glimpse.scene.writer import SceneWriter

DATASET = "zju-mocap"
MILLIMETRES_PER_METRE = 1000.0
DEFAULT_FPS = 30.0  # the dataset's files state no frame rate
PARAM_FOLDERS = ("new_params", "params")  # EasyMocap's refit with pose blend shapes first (HumanNeRF, GTU)
MASK_FOLDERS = ("mask", "mask_cihp")
PID = "p0"


def sequence_folder(source: Path, sequence: str | None) -> Path:
    """The sequence folder: SOURCE itself when it holds annots.npy, else SOURCE/CoreView_<sequence> (or
    SOURCE/<sequence>)."""
    source = Path(source)
    if (source / "annots.npy").is_file():
        return source
    if sequence is None:
        raise GlimpseError(f"{source}: no annots.npy; give a ZJU-MoCap sequence folder (CoreView_377/) or the "
                           "dataset folder with --sequence 377")
    for name in (f"CoreView_{sequence}", sequence):
        if (source / name / "annots.npy").is_file():
            return source / name
    raise GlimpseError(f"{source}: no CoreView_{sequence}/annots.npy (nor {sequence}/annots.npy)")


def read_annots(folder: Path) -> tuple[dict[str, np.ndarray], list[list[str]]]:
    """(cameras: K [C, 3, 3], D [C, 5], R [C, 3, 3], t [C, 3] metres; per frame, the C image paths)."""
    path = folder / "annots.npy"
    try:
        annots = load_object_npy(path)
        cams = annots["cams"]
        cameras = {"K": np.asarray(cams["K"], np.float64).reshape(-1, 3, 3),
                   "D": np.asarray(cams["D"], np.float64).reshape(len(cams["K"]), -1),
                   "R": np.asarray(cams["R"], np.float64).reshape(-1, 3, 3),
                   "t": np.asarray(cams["T"], np.float64).reshape(-1, 3) / MILLIMETRES_PER_METRE}
        images = [[str(p) for p in entry["ims"]] for entry in annots["ims"]]
    except (KeyError, TypeError, AttributeError, IndexError) as exc:
        raise GlimpseError(f"{path}: not ZJU-MoCap's annots.npy (a dict with cams K, D, R, T and ims): {exc}") from None
    count = len(cameras["K"])
    if not all(len(cameras[key]) == count for key in cameras) or any(len(paths) != count for paths in images):
        raise GlimpseError(f"{path}: every camera needs K, D, R and T, and every frame one image per camera "
                           f"({count} cameras)")
    return cameras, images


def params_index(image_path: str) -> int:
    """The SMPL file number of a frame, from its image name: ``000042.jpg`` -> 42; CoreView_313/315's
    ``CoreView_313_Camera_(1)_0001_<time>.jpg`` -> 1 (those sequences number from 1)."""
    stem = Path(image_path).stem
    if stem.isdigit():
        return int(stem)
    parts = stem.split("_")
    if len(parts) > 4 and parts[4].isdigit():
        return int(parts[4])
    raise GlimpseError(f"ZJU-MoCap image {image_path}: cannot tell its frame number from the name")


def person_mask(folder: Path, image_path: str) -> np.ndarray:
    """[H, W] bool: the union of mask/ and mask_cihp/ for one image (either may be absent, not both)."""
    found = [nonzero_mask(folder / name / Path(image_path).with_suffix(".png")) for name in MASK_FOLDERS]
    found = [mask for mask in found if mask is not None]
    if not found:
        raise GlimpseError(f"{folder}: no mask for {image_path} in {' or '.join(MASK_FOLDERS)}/")
    return np.logical_or.reduce(found)


def pick_cameras(requested: tuple[str, ...] | None, names: list[str]) -> tuple[int, list[int]]:
    """(input camera, held-out cameras) as indices into ``names``: ``requested`` lists the input first, each an
    index (0 = the first camera of annots.npy, as Neural Body and HumanNeRF count) or a folder name; default:
    camera 0 as input, every other one held out (HumanNeRF's protocol, which GTU follows)."""
    if not requested:
        return 0, list(range(1, len(names)))
    chosen = []
    for item in requested:
        if item.isdigit() and int(item) < len(names):
            chosen.append(int(item))
        elif item in names:
            chosen.append(names.index(item))
        else:
            raise GlimpseError(f"--cameras {item}: not a camera of this sequence (0..{len(names) - 1} or "
                               f"{', '.join(names[:3])}, ...)")
    return chosen[0], chosen[1:]


def import_zju_mocap(source: Path, scene_dir: Path, options: ImportOptions) -> Path:
    """Write the scene; returns its folder."""
    folder = sequence_folder(source, options.sequence)
    model_file = smpl_model_file(options, DATASET)
    cameras, images = read_annots(folder)
    if not images:
        raise GlimpseError(f"{folder / 'annots.npy'}: no frame")
    names = [Path(paths).parent.as_posix() for paths in images[0]]
    source_camera, heldout = pick_cameras(options.cameras, names)
    positions = list(range(len(images)))[options.frames or slice(None)]
    if not positions:
        raise GlimpseError(f"--frames selects no frame of {folder.name} ({len(images)} frames)")
    params = read_bodies(folder, [images[p][source_camera] for p in positions])
    pelvis = rest_pelvis(model_file, params["shapes"][0])
    global_orient, transl = pelvis_placed_smpl(params["poses"][:, :3], Rotation.from_rotvec(params["Rh"]),
                                               params["Th"], np.ones(len(positions)), pelvis, pelvis)
    body_pose = params["poses"][:, 3:72]

    writer = SceneWriter(scene_dir, name=f"zju_{folder.name}", fps=options.fps or DEFAULT_FPS,
                         camera_motion="static", body_model="smpl",
                         overrides={"body": {"model_path": str(model_file)}})
    width = height = 0
    for position in progress(positions, desc=f"{DATASET} {folder.name} input", unit="frame"):
        rgb = read_rgb(folder / images[position][source_camera])
        height, width = rgb.shape[:2]
        writer.frame(position, rgb)
        writer.person_mask(PID, position, person_mask(folder, images[position][source_camera]))
    pose = CameraPose(cameras["R"][source_camera], cameras["t"][source_camera])
    writer.input_cameras(width, height, cameras["K"][source_camera], cameras["D"][source_camera],
                         poses={position: pose for position in positions})
    writer.smpl(PID, np.asarray(positions), params["shapes"][0], global_orient, body_pose, transl)
    scored = positions[:: max(1, options.eval_every)]
    for index in progress(heldout, desc=f"{DATASET} {folder.name} held-out views", unit="camera"):
        held = HeldOutCamera(writer, camera_name(names[index]), cameras["K"][index], cameras["D"][index],
                             cameras["R"][index], cameras["t"][index])
        for position in scored:
            held.view(position, read_rgb(folder / images[position][index]),
                      {PID: person_mask(folder, images[position][index])})
    return writer.finish()


def read_bodies(folder: Path, image_paths: list[str]) -> dict[str, np.ndarray]:
    """poses [T, 72], Rh [T, 3], Th [T, 3] and shapes [T, 10] of the frames whose input images are
    ``image_paths``, from new_params/ (else params/)."""
    params_dir = next((folder / name for name in PARAM_FOLDERS if (folder / name).is_dir()), None)
    if params_dir is None:
        raise GlimpseError(f"{folder}: no {' or '.join(PARAM_FOLDERS)}/ folder of SMPL parameters")
    rows: dict[str, list[np.ndarray]] = {"poses": [], "Rh": [], "Th": [], "shapes": []}
    for image_path in image_paths:
        path = params_dir / f"{params_index(image_path)}.npy"
        try:
            entry = load_object_npy(path)
            for key in rows:
                rows[key].append(np.asarray(entry[key], np.float64).reshape(-1))
        except (ValueError, KeyError, TypeError, IndexError) as exc:
            raise GlimpseError(f"{path}: not an EasyMocap SMPL file (poses, Rh, Th, shapes): {exc}") from None
    params = {key: np.stack(values) for key, values in rows.items()}
    if np.abs(params["shapes"] - params["shapes"][0]).max() > 1e-6:
        raise GlimpseError(f"{params_dir}: the person's shape changes between frames; Glimpse needs one shape per "
                           "person")
    return params
