"""How close fitted bodies are to known ones (fixtures' ground truth): mean per-joint position
error over the 24 body joints of the fitted (not interpolated) frames, three ways:

- ``mpjpe_m``: in the world frame as fitted;
- ``sequence_aligned_m``: after one similarity (rotation, translation, scale) over the whole
  sequence, the "global alignment" that removes a 2D fit's depth/size ambiguity;
- ``frame_aligned_m``: after a similarity per frame (PA-MPJPE, as HMR papers report).

For a scene's people together, ``scene_scale_errors`` removes only what no single view can tell: the whole
scene scaled about the camera by one factor (placement_errors: how people stand relative to each other), and
``front_by_masks`` reads who hides whom from the people's masks where their skeletons overlap in the image, to
compare with the fitted and the true depth order. ``motion_errors`` says how the fitted bodies move against the
true ones: acceleration error, jitter, and foot skate where a true foot is planted.
"""

from __future__ import annotations

from dataclasses import replace
from math import comb

import cv2
import numpy as np
import torch
from scipy.optimize import minimize_scalar
from scipy.spatial.transform import Rotation

from glimpse.body.model import AXIS_ANGLE_DIM, BODY_POSE_DIM, BodyModel
from glimpse.body.params import BodyParams
from glimpse.cameras.align import Similarity, umeyama

SCENE_SCALE_BOUNDS = (0.25, 4.0)  # the common factor searched: a scene fitted 4 times too near or far is not a fit
SCENE_SCALE_TOLERANCE = 1e-9  # the factor to this (relative to 1: far below any error that matters)
PELVIS, NECK = 0, 12  # body joints: a projected torso's length, which sets how wide a skeleton is drawn
FEET = (10, 11)  # body joints left_foot, right_foot (the ball of the foot)
CONTACT_SPEED_M_S = 0.2  # a true foot slower than this between two consecutive frames is planted (a stance foot)


def body_joints(model: BodyModel, betas: np.ndarray, global_orient: np.ndarray, body_pose: np.ndarray,
                transl: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """[T, 24, 3] posed joints."""
    with torch.no_grad():
        out = model(torch.as_tensor(betas)[None], torch.as_tensor(global_orient), torch.as_tensor(body_pose),
                    torch.as_tensor(transl), scale=scale)
    return out.joints.numpy()


def true_joints(model: BodyModel, fitted: BodyParams, truth: dict[str, np.ndarray]) -> np.ndarray:
    """[T, 24, 3] the true joints in ``fitted``'s fitted (not interpolated) frames (truth as in ``joint_errors``)."""
    rows = np.searchsorted(truth["frame_ids"], fitted.frame_ids[~fitted.interpolated])
    return body_joints(model, truth["betas"], truth["global_orient"][rows], truth["body_pose"][rows],
                       truth["transl"][rows])


def joint_errors(model: BodyModel, fitted: BodyParams, truth: dict[str, np.ndarray]) -> dict[str, float]:
    """truth: betas [10] and per-frame global_orient, body_pose, transl indexed by ``truth['frame_ids']``."""
    keep = ~fitted.interpolated
    true = true_joints(model, fitted, truth)
    fit = body_joints(model, fitted.betas, fitted.global_orient[keep], fitted.body_pose[keep], fitted.transl[keep],
                      fitted.scale)
    whole = umeyama(fit.reshape(-1, 3), true.reshape(-1, 3))
    per_frame = [np.linalg.norm(umeyama(f, t).apply(f) - t, axis=1).mean() for f, t in zip(fit, true)]
    return {"frames": int(keep.sum()),
            "mpjpe_m": float(np.linalg.norm(fit - true, axis=-1).mean()),
            "sequence_aligned_m": float(np.linalg.norm(whole.apply(fit.reshape(-1, 3)) - true.reshape(-1, 3),
                                                       axis=1).mean()),
            "frame_aligned_m": float(np.mean(per_frame))}


def shape_errors(model: BodyModel, fitted: BodyParams, truth: dict[str, np.ndarray]) -> dict[str, float]:
    """How far the fitted body's shape is from the true one (truth as in ``joint_errors``), over the vertices of
    both in the rest pose (zero pose, each at its scale, their root joints together): ``surface_m``, the mean
    vertex distance, and ``surface_size_aligned_m``, the same after the fitted body is scaled about its root by
    the factor that fits best (its width and proportions, without the size one view cannot tell)."""
    def rest(betas: np.ndarray, scale: float) -> np.ndarray:
        with torch.no_grad():
            out = model(betas, torch.zeros(1, AXIS_ANGLE_DIM, dtype=model.dtype),
                        torch.zeros(1, BODY_POSE_DIM, dtype=model.dtype), scale=scale)
        return (out.vertices[0] - out.joints[0, 0]).numpy()

    fit, true = rest(fitted.betas, fitted.scale), rest(truth["betas"], float(truth.get("scale", 1.0)))
    factor = float((fit * true).sum() / (fit * fit).sum())
    return {"surface_m": float(np.linalg.norm(fit - true, axis=1).mean()),
            "surface_size_aligned_m": float(np.linalg.norm(factor * fit - true, axis=1).mean())}


def motion_errors(model: BodyModel, fitted: BodyParams, truth: dict[str, np.ndarray], fps: float
                  ) -> dict[str, float | int]:
    """How the fitted body moves, against the true one (truth as in ``joint_errors``), over runs of consecutive
    fitted (not interpolated) frames, derivatives by finite differences at the scene's ``fps``, in world units
    and seconds (a metric world: CONTACT_SPEED_M_S is in metres per second):

    - ``accel_error_m_s2``: mean | a_fit - a_true | of the 24 joints' accelerations (as video pose papers report
      it, but per second squared rather than per frame squared, so that 8 and 33 fps scenes compare);
    - ``jitter_m_s3`` and ``true_jitter_m_s3``: the mean magnitude of the joints' jerk, fitted and true;
    - ``foot_skate_m_s`` and ``true_foot_skate_m_s``: the mean speed of the fitted and the true feet (FEET) between
      consecutive frames where the true foot is planted (slower than CONTACT_SPEED_M_S), over ``contact_pairs``
      such foot-frame pairs. nan where the sequence has no such triple, quadruple or pair."""
    keep = ~fitted.interpolated
    ids = fitted.frame_ids[keep]
    fit = body_joints(model, fitted.betas, fitted.global_orient[keep], fitted.body_pose[keep], fitted.transl[keep],
                      fitted.scale)
    true = true_joints(model, fitted, truth)

    def differences(order: int) -> tuple[np.ndarray, np.ndarray]:
        """The ``order``-th differences (times fps^order) of fitted and true joints over windows of consecutive
        frames: each [N, 24, 3]."""
        starts = [t for t in range(len(ids) - order) if ids[t + order] - ids[t] == order]
        if not starts:
            return np.zeros((0, *fit.shape[1:])), np.zeros((0, *fit.shape[1:]))
        window = np.array(starts)[:, None] + np.arange(order + 1)
        weights = np.array([(-1) ** (order - k) * comb(order, k) for k in range(order + 1)], float)
        return (np.einsum("k,nkjc->njc", weights, fit[window]) * fps ** order,
                np.einsum("k,nkjc->njc", weights, true[window]) * fps ** order)

    mean_norm = lambda x: float(np.linalg.norm(x, axis=-1).mean()) if x.size else float("nan")
    accel_fit, accel_true = differences(2)
    jerk_fit, jerk_true = differences(3)
    speed_fit, speed_true = (np.linalg.norm(v[:, FEET], axis=-1) for v in differences(1))
    planted = speed_true < CONTACT_SPEED_M_S
    return {"accel_error_m_s2": mean_norm(accel_fit - accel_true),
            "jitter_m_s3": mean_norm(jerk_fit), "true_jitter_m_s3": mean_norm(jerk_true),
            "foot_skate_m_s": float(speed_fit[planted].mean()) if planted.any() else float("nan"),
            "true_foot_skate_m_s": float(speed_true[planted].mean()) if planted.any() else float("nan"),
            "contact_pairs": int(planted.sum())}


def moved_onto_truth(model: BodyModel, fitted: BodyParams,
                     truth: dict[str, np.ndarray]) -> tuple[BodyParams, Similarity]:
    """``fitted`` moved by the one similarity (rotation, translation, scale) that best aligns its joints in the
    fitted (not interpolated) frames to the true ones (truth as in ``joint_errors``), every frame moved alike: its
    placement and size made right, its pose kept. Returns (moved params, the similarity)."""
    joints = body_joints(model, fitted.betas, fitted.global_orient, fitted.body_pose, fitted.transl, fitted.scale)
    move = umeyama(joints[~fitted.interpolated].reshape(-1, 3), true_joints(model, fitted, truth).reshape(-1, 3))
    orient = (Rotation.from_matrix(move.rotation) * Rotation.from_rotvec(fitted.global_orient)).as_rotvec()
    return _rooted_at(model, fitted, orient, fitted.scale * move.scale, move.apply(joints[:, 0])), move


def scaled_about_cameras(model: BodyModel, fitted: BodyParams, centres: np.ndarray, factor: float) -> BodyParams:
    """``fitted`` moved about each frame's camera centre (``centres`` [T, 3], world, one per frame of ``fitted``) by
    ``factor``: every joint x of frame t to c_t + factor (x - c_t), the body scaled with it. It projects to the same
    pixels in every frame: the one change of a scene that 2D keypoints cannot see (scene_scale_errors)."""
    roots = body_joints(model, fitted.betas, fitted.global_orient, fitted.body_pose, fitted.transl, fitted.scale)[:, 0]
    return _rooted_at(model, fitted, fitted.global_orient, fitted.scale * factor, centres + factor * (roots - centres))


def _rooted_at(model: BodyModel, fitted: BodyParams, global_orient: np.ndarray, scale: float,
               roots: np.ndarray) -> BodyParams:
    """``fitted`` with ``global_orient`` [T, 3] and ``scale``, translated so that its root joint lies at ``roots``
    [T, 3] (world) in every frame; pose and shape kept."""
    unmoved_root = body_joints(model, fitted.betas, global_orient, fitted.body_pose, np.zeros_like(fitted.transl),
                               scale)[:, 0]
    return replace(fitted, global_orient=global_orient, transl=roots - unmoved_root, scale=scale)


def placement_errors(model: BodyModel, fitted: dict[str, BodyParams], truth: dict[str, dict[str, np.ndarray]],
                     camera_centres: dict[int, np.ndarray]) -> dict[str, float]:
    """How people are placed relative to each other, over every pair and the frames both were fitted in:
    ``pelvis_distance_error_m``, the mean of | |p_i - p_j| - |q_i - q_j| | (fitted pelvises p, true q);
    ``depth_order_agreement``, the fraction of (pair, frame) whose nearer person (pelvis distance from
    the camera centre [3] of that frame) is the true nearer one; and ``depth_order_largest_miss_m``, over the
    (pair, frame) whose order is wrong, the largest difference of the two true pelvis distances from the camera
    (0 when none is wrong: how far apart in depth the people were where the order failed). nan without a pair."""
    pelvis = {}
    for pid, params in fitted.items():
        keep = ~params.interpolated
        ours = body_joints(model, params.betas, params.global_orient[keep], params.body_pose[keep],
                           params.transl[keep], params.scale)[:, 0]
        true = true_joints(model, params, truth[pid])[:, 0]
        pelvis[pid] = {int(f): (o, q) for f, o, q in zip(params.frame_ids[keep], ours, true)}
    distance_errors, agreements, missed_gaps = [], [], [0.0]
    pids = sorted(pelvis)
    for a, pid in enumerate(pids):
        for other in pids[a + 1:]:
            for frame in sorted(set(pelvis[pid]) & set(pelvis[other])):
                (p, q), (p2, q2) = pelvis[pid][frame], pelvis[other][frame]
                distance_errors.append(abs(np.linalg.norm(p - p2) - np.linalg.norm(q - q2)))
                centre = camera_centres[frame]
                true_gap = np.linalg.norm(q - centre) - np.linalg.norm(q2 - centre)
                in_order = (np.linalg.norm(p - centre) < np.linalg.norm(p2 - centre)) == (true_gap < 0)
                agreements.append(in_order)
                if not in_order:
                    missed_gaps.append(abs(float(true_gap)))
    if not distance_errors:
        return {"pelvis_distance_error_m": float("nan"), "depth_order_agreement": float("nan"),
                "depth_order_largest_miss_m": float("nan")}
    return {"pelvis_distance_error_m": float(np.mean(distance_errors)),
            "depth_order_agreement": float(np.mean(agreements)), "depth_order_largest_miss_m": max(missed_gaps)}


def scene_scale_errors(model: BodyModel, fitted: dict[str, BodyParams], truth: dict[str, dict[str, np.ndarray]],
                       camera_centres: dict[int, np.ndarray]) -> tuple[float, dict[str, float]]:
    """The error of a scene's fits up to the one thing a single view cannot tell: every person scaled about the
    camera centre by one common factor projects to the same pixels (every frame about that frame's camera centre
    [3], ``camera_centres`` by frame id), so 2D keypoints fix a scene only up to that factor; a metric cue (a
    stated height, a known camera height) is what sets it. Each fitted joint x of frame t (fitted, not
    interpolated frames; truth as in ``joint_errors``) is moved to c_t + s (x - c_t), s the factor that gives the
    smallest mean per-joint error over all people and frames (a convex function of s, so never more than with
    s = 1, as fitted). Returns (s, pid -> mean per-joint error after it, world units). Unlike the per-person
    alignments of ``joint_errors`` this keeps every person's placement relative to the others and to the camera:
    one person misplaced stays misplaced."""
    offsets = {}  # pid -> (fitted joints - centre, true joints - centre), each [T * 24, 3]
    for pid, params in fitted.items():
        keep = ~params.interpolated
        centres = np.stack([camera_centres[int(f)] for f in params.frame_ids[keep]])[:, None]
        fit = body_joints(model, params.betas, params.global_orient[keep], params.body_pose[keep],
                          params.transl[keep], params.scale)
        true = true_joints(model, params, truth[pid])
        offsets[pid] = ((fit - centres).reshape(-1, 3), (true - centres).reshape(-1, 3))
    fit_all = np.concatenate([f for f, _ in offsets.values()])
    true_all = np.concatenate([t for _, t in offsets.values()])
    mean_error = lambda s: float(np.linalg.norm(s * fit_all - true_all, axis=1).mean())
    found = minimize_scalar(mean_error, bounds=SCENE_SCALE_BOUNDS, method="bounded",
                            options={"xatol": SCENE_SCALE_TOLERANCE})
    scale = float(found.x) if mean_error(found.x) <= mean_error(1.0) else 1.0
    return scale, {pid: float(np.linalg.norm(scale * f - t, axis=1).mean()) for pid, (f, t) in offsets.items()}


def floor_errors(normal: np.ndarray, camera_height: float, camera_centre: np.ndarray, R: np.ndarray,
                 true_up: np.ndarray, true_floor_height: float = 0.0) -> dict[str, float]:
    """How a fitted floor (stage 02's ground.json: unit ``normal`` [3], the camera centre [3] ``camera_height``
    above it; world) compares with the true one (``true_up`` [3], the floor at ``true_floor_height`` along it):

    - ``tilt_deg``: the angle between the two normals;
    - ``pitch_error_deg``, ``roll_error_deg``: that angle split in the camera's axes (``R`` [3, 3]
      world-to-camera, OpenCV: x right, y down, z forward): the fitted up leaning towards the camera's
      viewing direction (pitch: what the torso axes of people in one image column cannot tell) or sideways
      (roll), fitted minus true, degrees;
    - ``camera_height_error_m``: the fitted camera height minus the true one (world units).
    """
    def tilts(up: np.ndarray) -> tuple[float, float]:
        up_cam = R @ (up / np.linalg.norm(up))  # in the camera's axes; a level camera sees it as (0, -1, 0)
        return (float(np.degrees(np.arctan2(up_cam[2], -up_cam[1]))),
                float(np.degrees(np.arctan2(up_cam[0], -up_cam[1]))))

    normal = np.asarray(normal, float) / np.linalg.norm(normal)
    true_up = np.asarray(true_up, float) / np.linalg.norm(true_up)
    (pitch, roll), (true_pitch, true_roll) = tilts(normal), tilts(true_up)
    true_height = float(np.asarray(camera_centre, float) @ true_up - true_floor_height)
    return {"tilt_deg": float(np.degrees(np.arccos(np.clip(normal @ true_up, -1.0, 1.0)))),
            "pitch_error_deg": pitch - true_pitch, "roll_error_deg": roll - true_roll,
            "camera_height_error_m": float(camera_height) - true_height}


def skeleton_pixels(points: np.ndarray, parents: list[int], radius_px: float, shape: tuple[int, int]) -> np.ndarray:
    """[H, W] bool: the pixels within ``radius_px`` of the bones (joint to parent) of [J, 2] projected joints."""
    image = np.zeros(shape, np.uint8)
    thickness = max(1, round(2 * radius_px))
    for joint, parent in enumerate(parents):
        if parent >= 0:
            cv2.line(image, tuple(int(round(v)) for v in points[joint]), tuple(int(round(v)) for v in points[parent]),
                     1, thickness)
    return image.astype(bool)


def front_by_masks(points_a: np.ndarray, points_b: np.ndarray, mask_a: np.ndarray, mask_b: np.ndarray,
                   parents: list[int], radius_torsos: float, min_pixels: int, min_share: float,
                   max_minority: float) -> int | None:
    """Who of two people the masks put in front where their projected skeletons overlap: 0 (a) or 1 (b), or None
    when they do not tell. points_* [J, 2] projected body joints (pixels), mask_* [H, W] bool the people's visible
    masks. Each skeleton is drawn ``radius_torsos`` of its projected torso (pelvis to neck) wide; where the two
    drawings overlap in at least ``min_pixels`` pixels, the person in front owns them: the masks tell when one mask
    covers at least ``min_share`` of the overlap and the other at most ``max_minority`` times as much."""
    shape = mask_a.shape
    regions = [skeleton_pixels(p, parents, radius_torsos * float(np.linalg.norm(p[PELVIS] - p[NECK])), shape)
               for p in (points_a, points_b)]
    overlap = regions[0] & regions[1]
    area = int(np.count_nonzero(overlap))
    if area < min_pixels:
        return None
    owned = [int(np.count_nonzero(mask & overlap)) for mask in (mask_a, mask_b)]
    front = int(np.argmax(owned))
    if owned[front] < min_share * area or owned[1 - front] > max_minority * owned[front]:
        return None
    return front
