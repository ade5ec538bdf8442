"""NeuMan (one person filmed by a moving phone; COLMAP cameras, SMPL fitted per frame) as a glimpse-scene/1
folder: the video's training frames as input, its test frames as held-out views (docs/datasets.md).

The source, one sequence folder (``bike/``; read from NeuMan's preprocessing and loader, and HUGS's loader):

    images/00000.png ...        every 10th frame of the phone video, undistorted by COLMAP
    sparse/cameras.txt, images.txt, points3D.txt      COLMAP's model (world to camera, COLMAP's units)
    segmentations/00000.png     the person = 0, background = 255 (Mask R-CNN); ``<name>.npy`` is read first
    keypoints/00000.png.npy     (17, 3) COCO-17 x, y, score (optional)
    smpl_output_optimized.pkl   joblib: {1: {"pose": N x (72,), "betas": N x (10,)}}, indexed by the frame
                                number of the image name (``smpl_output_romp.pkl`` when there is no optimized one)
    alignments.npy              {image name: A (4, 3)}: A.T is the similarity [s R | T] that takes the frame's
                                SMPL body (posed, no translation) into COLMAP's world; s differs per frame
    4d_humans/                  (HUGS's copy) smpl_optimized_aligned_scale.npz with global_orient, body_pose,
                                transl, scale and betas per capture (body = scale · SMPL + transl) and
                                sam_segmentations/*.png (the person = 255), read when NeuMan's own files are absent

COLMAP's world has no unit. The scene's world is COLMAP's divided by the median of the per-frame scales s (which
make the SMPL body, in metres, the size of the person in COLMAP's units): the body keeps its size and every
camera is placed in metres. A body is written at unit scale with its pelvis where NeuMan puts it; a frame whose
scale differs from the median by x% has the rest of the body x% too large or small about the pelvis (recorded
in the scene's ``neuman_import.json``). NeuMan's betas may change per frame: the scene's person gets their
mean, each frame's pelvis placed with its own. Frames: NeuMan's protocol split (every fifth registered image;
the first half of those are the test frames, scored as held-out views of the moving camera; the second half,
its validation frames, are left out; the rest are the input).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image
from scipy.spatial.transform import Rotation

from glimpse.cameras.undistort import Undistorter
from glimpse.errors import GlimpseError
from glimpse.importers.common import ImportOptions, pelvis_placed_smpl, rest_pelvis, smpl_model_file
from glimpse.io.colmap_model import ColmapShot, read_colmap_model
from glimpse.io.images import read_rgb
from glimpse.io.numpy_pickle import load_joblib_pickle, load_object_npy, load_object_npz
from glimpse.io.progress import progress
from glimpse.scene.model import CameraPose
from glimpse.scene.writer import SceneWriter

DATASET = "neuman"
DEFAULT_FPS = 3.0  # NeuMan's preprocessing keeps every 10th frame of a 30 fps phone video
PID = "p0"
HELD_OUT_CAMERA = "video_test"  # the input camera at NeuMan's test frames
SMPL_FILES = ("smpl_output_optimized.pkl", "smpl_output_romp.pkl")  # NeuMan's loader default first
HUGS_SMPL = "4d_humans/smpl_optimized_aligned_scale.npz"
HUGS_MASKS = "4d_humans/sam_segmentations"
SPLIT_EVERY = 5  # NeuMan's split: one frame in five is held out (half test, half validation)
ALIGNMENT_ROTATION_TOLERANCE = 1e-4  # how far A.T[:3, :3] / s may be from a rotation (float32 files)
REPORT_FILE = "neuman_import.json"


@dataclass(frozen=True)
class PlacedBodies:
    """A sequence's SMPL bodies as the source places them, per frame: X = scale · turn · SMPL(betas,
    global_orient, body_pose, transl=0) + shift, in COLMAP's world. positions: indices into the registered
    images; global_orient [T, 3], body_pose [T, 69], betas [T, 10], shift [T, 3], scale [T]."""

    positions: list[int]
    global_orient: np.ndarray
    body_pose: np.ndarray
    betas: np.ndarray
    turn: Rotation
    shift: np.ndarray
    scale: np.ndarray
    source: str


def sequence_folder(source: Path, sequence: str | None) -> Path:
    """The folder holding sparse/ and images/: SOURCE, or SOURCE/<sequence>."""
    for folder in (source, source / sequence if sequence else None):
        if folder is not None and (folder / "sparse").is_dir() and (folder / "images").is_dir():
            return folder
    raise GlimpseError(f"{source}: no sparse/ and images/; give a NeuMan sequence folder (bike/) or the dataset "
                       "folder with --sequence bike")


def protocol_split(count: int) -> tuple[list[int], list[int], list[int]]:
    """NeuMan's (train, validation, test) positions among ``count`` registered images, sorted by name: every
    fifth image from the middle of the first five is held out; the first half of those is the test set."""
    held = count // SPLIT_EVERY
    if held == 0:
        return list(range(count)), [], []
    step = int(1 / held * count)  # as NeuMan computes it (floating point)
    held_out = list(range(count))[step // 2:: step]
    test, validation = held_out[: len(held_out) // 2], held_out[len(held_out) // 2:]
    return [p for p in range(count) if p not in held_out], validation, test


def alignment_similarity(A: np.ndarray, where: str) -> tuple[np.ndarray, float, np.ndarray]:
    """(R [3, 3], s, T [3]) of an alignments.npy entry A (4, 3): A.T = [s R | T]."""
    M = np.asarray(A, np.float64).T
    if M.shape != (3, 4) or not np.isfinite(M).all():
        raise GlimpseError(f"{where}: expected a finite (4, 3) array, found {np.shape(A)}")
    scale = float(np.cbrt(np.linalg.det(M[:, :3])))
    rotation = M[:, :3] / scale if scale > 0 else M[:, :3]
    if scale <= 0 or np.abs(rotation @ rotation.T - np.eye(3)).max() > ALIGNMENT_ROTATION_TOLERANCE:
        raise GlimpseError(f"{where}: A.T[:3, :3] is not a positive scale times a rotation")
    return rotation, scale, M[:, 3]


def neuman_bodies(folder: Path, shots: list[ColmapShot]) -> PlacedBodies | None:
    """NeuMan's own bodies (smpl_output_*.pkl with alignments.npy), None when the files are absent."""
    path = next((folder / name for name in SMPL_FILES if (folder / name).is_file()), None)
    if path is None or not (folder / "alignments.npy").is_file():
        return None
    people = load_joblib_pickle(path)
    if not isinstance(people, dict) or len(people) != 1:
        raise GlimpseError(f"{path}: expected one person's parameters ({{1: {{'pose', 'betas'}}}})")
    person = next(iter(people.values()))
    alignments = load_object_npy(folder / "alignments.npy")
    if not isinstance(alignments, dict):
        raise GlimpseError(f"{folder / 'alignments.npy'}: expected a dict of image name -> (4, 3) array")
    rows: dict[str, list] = {"positions": [], "pose": [], "betas": [], "R": [], "s": [], "T": []}
    for position, shot in enumerate(shots):
        number = frame_number(shot.name)
        if shot.name not in alignments:
            continue  # NeuMan aligns the frames COLMAP registered and ROMP found the person in
        try:
            pose = np.asarray(person["pose"][number], np.float64).reshape(72)
            betas = np.asarray(person["betas"][number], np.float64).reshape(-1)[:10]
        except (KeyError, IndexError, ValueError, TypeError) as exc:
            raise GlimpseError(f"{path}: no pose (72) and betas (10) for frame {number} ({exc})") from None
        R, s, T = alignment_similarity(alignments[shot.name], f"{folder / 'alignments.npy'}[{shot.name!r}]")
        for key, value in zip(rows, (position, pose, betas, R, s, T)):
            rows[key].append(value)
    if not rows["positions"]:
        return None
    pose = np.stack(rows["pose"])
    return PlacedBodies(rows["positions"], pose[:, :3], pose[:, 3:], np.stack(rows["betas"]),
                        Rotation.from_matrix(np.stack(rows["R"])), np.stack(rows["T"]), np.asarray(rows["s"]),
                        f"{path.name} and alignments.npy")


def hugs_bodies(folder: Path, shots: list[ColmapShot]) -> PlacedBodies | None:
    """HUGS's bodies (4d_humans/smpl_optimized_aligned_scale.npz, one row per registered image), or None."""
    path = folder / HUGS_SMPL
    if not path.is_file():
        return None
    data = load_object_npz(path)
    count = len(shots)
    try:
        betas = np.asarray(data["betas"], np.float64).reshape(-1, 10)
        fields = {key: np.asarray(data[key], np.float64).reshape(count, width) for key, width in
                  (("global_orient", 3), ("body_pose", 69), ("transl", 3), ("scale", 1))}
    except (KeyError, ValueError) as exc:
        raise GlimpseError(f"{path}: expected global_orient, body_pose, transl, scale and betas for each of the "
                           f"{count} registered images ({type(exc).__name__}: {exc})") from None
    return PlacedBodies(list(range(count)), fields["global_orient"], fields["body_pose"],
                        np.broadcast_to(betas, (count, 10)) if len(betas) == 1 else betas,
                        Rotation.identity(count), fields["transl"], fields["scale"][:, 0], HUGS_SMPL)


def frame_number(name: str) -> int:
    """The frame number of a NeuMan image name (``00042.png`` -> 42), which indexes its SMPL file."""
    stem = Path(name).stem
    if not stem.isdigit():
        raise GlimpseError(f"NeuMan image {name}: expected a numbered name (00042.png)")
    return int(stem)


def person_mask(folder: Path, name: str, position: int) -> np.ndarray:
    """[H, W] bool: NeuMan's segmentation (person 0; ``.npy`` first, as its loader reads) or HUGS's SAM mask
    (person 255: the file of the image's name, else the position-th file in name order, as HUGS reads them)."""
    for path in (folder / "segmentations" / f"{name}.npy", folder / "segmentations" / name):
        if path.is_file():
            values = load_object_npy(path) if path.suffix == ".npy" else np.asarray(Image.open(path))
            return (values if values.ndim == 2 else values[..., 0]) == 0
    same_name = folder / HUGS_MASKS / name
    sam = [same_name] if same_name.is_file() else sorted((folder / HUGS_MASKS).glob("*.png"))[position:]
    if sam:
        return np.asarray(Image.open(sam[0]).convert("L")) > 127
    raise GlimpseError(f"{folder}: no mask for {name} in segmentations/ or {HUGS_MASKS}/")


def coco_keypoints(folder: Path, name: str) -> np.ndarray | None:
    """(17, 3) x, y, confidence (0 to 1) from keypoints/<name>.npy; None when the file is absent."""
    path = folder / "keypoints" / f"{name}.npy"
    if not path.is_file():
        return None
    keypoints = np.asarray(load_object_npy(path), np.float64)
    if keypoints.shape != (17, 3):
        raise GlimpseError(f"{path}: expected (17, 3) COCO-17 x, y, score, found {keypoints.shape}")
    return np.concatenate([keypoints[:, :2], np.clip(keypoints[:, 2:], 0.0, 1.0)], axis=1)


def import_neuman(source: Path, scene_dir: Path, options: ImportOptions) -> Path:
    """Write the scene; returns its folder."""
    folder = sequence_folder(source, options.sequence)
    model_file = smpl_model_file(options, DATASET)
    shots = read_colmap_model(folder / "sparse")
    if any(not np.array_equal(s.K, shots[0].K) or (s.width, s.height) != (shots[0].width, shots[0].height)
           for s in shots):
        raise GlimpseError(f"{folder / 'sparse'}: several cameras; NeuMan's sequences have one (single_camera)")
    bodies = neuman_bodies(folder, shots) or hugs_bodies(folder, shots)
    if bodies is None:
        raise GlimpseError(f"{folder}: no bodies: give {' or '.join(SMPL_FILES)} with alignments.npy, or {HUGS_SMPL}")
    train, validation, test = protocol_split(len(shots))
    chosen = set(list(range(len(shots)))[options.frames or slice(None)])
    inputs = [p for p in train if p in chosen]
    if not inputs:
        raise GlimpseError(f"--frames selects no training frame of {folder.name} ({len(shots)} registered images)")
    scored = [p for p in test if p in chosen and inputs[0] < p < inputs[-1]]
    input_set = set(inputs)
    with_body = [row for row, p in enumerate(bodies.positions) if p in input_set]
    if not with_body:
        raise GlimpseError(f"{folder}: no training frame of the chosen span has a body ({bodies.source})")
    world_scale = float(np.median(bodies.scale[with_body]))  # COLMAP units per metre
    numbers = [frame_number(shot.name) for shot in shots]
    poses = {p: CameraPose(shots[p].R, shots[p].t / world_scale) for p in range(len(shots))}

    writer = SceneWriter(scene_dir, name=f"neuman_{folder.name}", fps=options.fps or DEFAULT_FPS,
                         camera_motion="moving", body_model="smpl", overrides={"body": {"model_path": str(model_file)}})
    camera = shots[0]
    for p in progress(inputs, desc=f"{DATASET} {folder.name}", unit="frame"):
        writer.frame(numbers[p], read_rgb(folder / "images" / shots[p].name))
        writer.person_mask(PID, numbers[p], person_mask(folder, shots[p].name, p))
    writer.input_cameras(camera.width, camera.height, camera.K, camera.dist,
                         poses={numbers[p]: poses[p] for p in inputs})
    keypoints = [coco_keypoints(folder, shots[p].name) for p in inputs]
    if any(k is not None for k in keypoints):  # a frame without a file: every point missing (confidence 0)
        writer.keypoints2d(PID, np.asarray([numbers[p] for p in inputs]), "coco17",
                           np.stack([np.zeros((17, 3)) if k is None else k for k in keypoints]))
    relative_scale = bodies.scale[with_body] / world_scale
    betas = write_bodies(writer, model_file, bodies, with_body, world_scale,
                         [numbers[bodies.positions[row]] for row in with_body])
    if scored:
        write_test_views(writer, folder, camera, {numbers[p]: (p, poses[p]) for p in scored}, shots)
    report = {"bodies": bodies.source, "colmap_units_per_metre": world_scale,
              "body_scale_relative": {"min": float(relative_scale.min()), "max": float(relative_scale.max())},
              "betas_spread": float(np.abs(bodies.betas[with_body] - betas).max()),
              "frames": {"input": len(inputs), "test (held out)": len(scored),
                         "validation (left out)": len([p for p in validation if p in chosen])}}
    writer.side_file(REPORT_FILE).write_text(json.dumps(report, indent=2))
    return writer.finish()


def write_bodies(writer: SceneWriter, model_file: Path, bodies: PlacedBodies, rows: list[int], world_scale: float,
                 numbers: list[int]) -> np.ndarray:
    """smpl.npz of the bodies' ``rows`` (frame ``numbers``) in the scene's world (COLMAP's / world_scale): the
    mean betas, each pelvis where the source puts it; returns the betas."""
    betas = bodies.betas[rows].mean(axis=0)
    pelvises = rest_pelvis(model_file, np.concatenate([bodies.betas[rows], betas[None]]))  # each frame's, the mean's
    global_orient, transl = pelvis_placed_smpl(
        bodies.global_orient[rows], bodies.turn[rows], bodies.shift[rows] / world_scale,
        bodies.scale[rows] / world_scale, pelvises[:-1], pelvises[-1])
    writer.smpl(PID, np.asarray(numbers), betas, global_orient, bodies.body_pose[rows], transl)
    return betas


def write_test_views(writer: SceneWriter, folder: Path, camera: ColmapShot,
                     scored: dict[int, tuple[int, CameraPose]], shots: list[ColmapShot]) -> None:
    """eval/video_test/: the test frames (frame number -> (position, pose)) as views of the moving input
    camera, undistorted to its K, with the person's mask."""
    undistorter = Undistorter(camera.K, camera.dist, camera.width, camera.height)
    start = scored[min(scored)][1]
    writer.eval_camera(HELD_OUT_CAMERA, camera.width, camera.height, camera.K, start.R, start.t,
                       poses={number: pose for number, (_, pose) in scored.items()})
    for number, (position, _) in progress(sorted(scored.items()), desc=f"{DATASET} {folder.name} test frames",
                                          unit="frame"):
        name = shots[position].name
        mask = undistorter.mask(person_mask(folder, name, position))
        writer.eval_view(HELD_OUT_CAMERA, number, undistorter.image(read_rgb(folder / "images" / name)), mask,
                         {PID: mask})
