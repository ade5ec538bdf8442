"""Fitting one person's body to keypoints over time: an initial guess, a global stage, pose hypotheses
(2D), a full stage.

1. Initial guess, per frame. 3D: the similarity (rotation, translation, and scale where fitted)
   that best maps the standing body's torso keypoints (shoulders, hips) onto the observed ones
   (Umeyama). 2D: a standing body facing the camera, turned around when the person's left
   shoulder and hip appear on the image's left (the person faces away); its depth from the
   keypoints' spread in pixels against the body's spread in metres; placed on the ray through
   the keypoints' centre. Pose: the pose prior's mean; betas 0.
2. Global stage: orientation, translation (and scale) against the torso and head keypoints.
   In 2D every frame is also tried turned by 90, 180 and 270 degrees about its up axis, and the
   sequence of turns that explains the keypoints best without spinning round between frames is
   kept (choose_turns).
3. Pose hypotheses (2D): each frame started again from several poses spread over the prior's
   motions and minimised alone; per frame the hypothesis that explains it best without the body
   changing shape between frames is kept (a crouch whose thighs point at the camera is a saddle
   of the 2D energy for a body started standing). With ``unseen_limbs_at_rest`` a limb no keypoint
   shows in a frame starts every hypothesis there at the global stage's pose.
4. Full stage: everything, with the priors; the pose prior's weight annealed from strong to
   its final value (SMPLify) while the robust scale shrinks from wide (a limb far from its
   keypoints still feels them) to its final value (outliers count little), each step minimised
   by L-BFGS with a strong-Wolfe line search.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial.transform import Rotation
from torch import Tensor

from glimpse.body.motion import SMPL_BODY_JOINTS
from glimpse.cameras.align import umeyama
from glimpse.errors import GlimpseError
from glimpse.fit.keypoint_body import KeypointBody
from glimpse.fit.objective import (FitEnergy, FitState, Track, acceleration_energy, motion_stride, repeat_frames,
                                    speed_energy)
from glimpse.fit.priors import pose_indices

TORSO = ("left_shoulder", "right_shoulder", "left_hip", "right_hip")
HEAD = ("nose", "left_eye", "right_eye", "left_ear", "right_ear")  # tell which way a profile faces
YAW_HYPOTHESES_DEG = (0.0, 90.0, 180.0, 270.0)  # 2D global stage: turns about the body's up axis tried
LEFT_RIGHT_PAIRS = (("left_shoulder", "right_shoulder"), ("left_hip", "right_hip"))
# With unseen_limbs_at_rest, the limbs the pose hypotheses leave at the global stage's pose in frames where none of
# their end keypoints is seen: (the SMPL body joints whose rotations they hold, the keypoints that see them).
UNSEEN_LIMBS = tuple(
    ((f"{side}_collar", f"{side}_shoulder", f"{side}_elbow", f"{side}_wrist", f"{side}_hand"),
     (f"{side}_elbow", f"{side}_wrist")) for side in ("left", "right")) + tuple(
    ((f"{side}_hip", f"{side}_knee", f"{side}_ankle", f"{side}_foot"),
     (f"{side}_knee", f"{side}_ankle", f"{side}_heel", f"{side}_big_toe", f"{side}_small_toe"))
    for side in ("left", "right"))
LBFGS_HISTORY = 20  # L-BFGS memory (pairs of updates); torch's default is 100, 20 is ample at this size


@dataclass(frozen=True)
class FitSchedule:
    global_iterations: int  # L-BFGS iterations of the global stage
    full_iterations: int  # L-BFGS iterations per annealing step of the full stage
    pose_prior_anneal: tuple[float, ...]  # multipliers of the pose-prior weight, one per step, last = 1
    robust_scale_anneal: tuple[float, ...]  # multipliers of the robust scale, one per step
    fit_scale: bool  # optimise the person's scale (world units per metre): frames in SfM units
    scale_motion_rate_hz: float  # the scale's motion test samples the pelvis path at about this rate
    hypothesis_iterations: int = 0  # 2D: L-BFGS iterations of the pose-hypotheses stage (0: no such stage)
    hypothesis_joint_speed_m_s: float = 1.0  # 2D: changing hypothesis between frames costs joint speed / this
    hypothesis_rate_hz: float = 8.0  # 2D: ... with frames judged at least 1 / this apart (seconds)
    unseen_limbs_at_rest: bool = False  # 2D: the hypotheses leave limbs no keypoint shows at the global stage's pose
    shape_stated: bool = False  # the initial state's betas are the person's known shape (person_shapes): held fixed


@dataclass
class FitOutcome:
    state: FitState
    stages: list[dict]  # per stage: name, iterations, energy terms at its end


def _torso_indices(body: KeypointBody) -> list[int]:
    missing = [name for name in TORSO if name not in body.names]
    if missing:
        raise GlimpseError(f"layout {body.layout} lacks the torso keypoints {missing} the fit starts from")
    return [body.names.index(name) for name in TORSO]


def _global_indices(body: KeypointBody) -> list[int]:
    return _torso_indices(body) + [body.names.index(name) for name in HEAD if name in body.names]


def mean_shape_keypoints(body: KeypointBody, pose: Tensor) -> tuple[np.ndarray, np.ndarray]:
    """Keypoints [K, 3] and root joint [3] of the mean-shape body in ``pose`` [69], unrotated, at the origin."""
    zero = torch.zeros(1, 3, dtype=pose.dtype)
    with torch.no_grad():
        out = body(torch.zeros(10, dtype=pose.dtype), zero, pose[None], zero, torch.ones((), dtype=pose.dtype))
    return out.keypoints[0].numpy(), out.joints[0, 0].numpy()


def _transl_placing(rotation: np.ndarray, scale: float, root: np.ndarray, point_body: np.ndarray,
                    point_world: np.ndarray) -> np.ndarray:
    """transl that puts body-frame ``point_body`` at ``point_world`` (the root turns about itself:
    x_world = scale * (rotation @ (x - root) + root) + transl)."""
    return point_world - scale * (rotation @ (point_body - root) + root)


def _nearest_filled(values: list, default):
    """Fill None entries from the nearest frame that has a value (default where none has)."""
    known = [i for i, v in enumerate(values) if v is not None]
    if not known:
        return [default] * len(values)
    return [v if v is not None else values[min(known, key=lambda k: abs(k - i))] for i, v in enumerate(values)]


def initial_state_3d(body: KeypointBody, track: Track, pose: Tensor, fit_scale: bool) -> FitState:
    torso = _torso_indices(body)
    rest, root = mean_shape_keypoints(body, pose)
    points, weight = track.points.numpy(), track.weight.numpy()
    solved: list = []
    for t in range(len(points)):
        seen = [k for k in torso if weight[t, k] > 0]
        if len(seen) < 3:
            seen = list(np.nonzero(weight[t] > 0)[0])
        if len(seen) < 3:
            solved.append(None)
            continue
        sim = umeyama(rest[seen], points[t, seen])
        scale = sim.scale if fit_scale else 1.0
        centre_body, centre_world = rest[seen].mean(0), points[t, seen].mean(0)
        solved.append((sim.rotation, scale, _transl_placing(sim.rotation, scale, root, centre_body, centre_world)))
    filled = _nearest_filled(solved, None)
    if filled[0] is None:
        raise GlimpseError("no frame has three keypoints to place the body from")
    return _state(pose, [f[0] for f in filled], [f[2] for f in filled], float(np.median([f[1] for f in filled])))


def initial_state_2d(body: KeypointBody, track: Track, pose: Tensor) -> FitState:
    rest, root = mean_shape_keypoints(body, pose)
    points, weight = track.points.numpy(), track.weight.numpy()
    K, R, t = track.K.numpy(), track.R.numpy(), track.t.numpy()
    facing: list = []
    for f in range(len(points)):
        votes = [points[f, body.names.index(a), 0] - points[f, body.names.index(b), 0]
                 for a, b in LEFT_RIGHT_PAIRS
                 if weight[f, body.names.index(a)] > 0 and weight[f, body.names.index(b)] > 0]
        facing.append(None if not votes else bool(np.sum(votes) >= 0))  # the person's left on the image right
    facing = _nearest_filled(facing, True)
    rotations, transls = [], []
    for f in range(len(points)):
        up, forward = -R[f][1], (-R[f][2] if facing[f] else R[f][2])  # body y = image up; body z = towards camera
        rotation = np.stack([np.cross(up, forward), up, forward], axis=1)  # columns: body x, y, z in the world
        seen = np.nonzero(weight[f] > 0)[0]
        offsets = (R[f] @ rotation @ (rest[seen] - rest[seen].mean(0)).T).T[:, :2]  # metres, camera x-y
        pixel_spread = np.sqrt(((points[f, seen] - points[f, seen].mean(0)) ** 2).sum(1).mean())
        focal = 0.5 * (K[f, 0, 0] + K[f, 1, 1])
        depth = focal * np.sqrt((offsets**2).sum(1).mean()) / max(pixel_spread, 1e-9)
        ray = np.linalg.solve(K[f], np.append(points[f, seen].mean(0), 1.0))
        centre_world = R[f].T @ (depth * ray - t[f])
        rotations.append(rotation)
        transls.append(_transl_placing(rotation, 1.0, root, rest[seen].mean(0), centre_world))
    return _state(pose, rotations, transls, 1.0)


def _state(pose: Tensor, rotations: list[np.ndarray], transls: list[np.ndarray], scale: float) -> FitState:
    dtype, frames = pose.dtype, len(rotations)
    return FitState(betas=torch.zeros(10, dtype=dtype),
                    global_orient=torch.as_tensor(Rotation.from_matrix(np.stack(rotations)).as_rotvec(), dtype=dtype),
                    body_pose=pose[None].repeat(frames, 1).clone(),
                    transl=torch.as_tensor(np.stack(transls), dtype=dtype),
                    log_scale=torch.tensor(float(np.log(scale)), dtype=dtype))


def _minimise(energy: FitEnergy, state: FitState, names: list[str], iterations: int, who: str,
              stage: str) -> dict:
    """L-BFGS on the listed FitState fields; raises a clear error when the energy stops being finite."""
    variables = [getattr(state, n).requires_grad_(True) for n in names]
    optimiser = torch.optim.LBFGS(variables, lr=1.0, max_iter=iterations, history_size=LBFGS_HISTORY,
                                  line_search_fn="strong_wolfe", tolerance_grad=1e-10, tolerance_change=1e-12)

    def closure() -> Tensor:
        optimiser.zero_grad()
        value = energy(state)
        if not torch.isfinite(value):
            raise GlimpseError(f"{who}: the fit diverged (energy {float(value.detach())}) in its {stage} stage; "
                               f"check the keypoints for outliers or the cameras from stage 01")
        value.backward()
        return value

    optimiser.step(closure)
    for n in names:
        getattr(state, n).requires_grad_(False)
        if not torch.isfinite(getattr(state, n)).all():
            raise GlimpseError(f"{who}: the fit diverged (non-finite {n}) in its {stage} stage")
    with torch.no_grad():
        terms = {k: float(v) for k, v in energy.terms(state).items()}
    return {"stage": stage, "iterations": int(optimiser.state[variables[0]]["n_iter"]), "energy": terms}


def fit_track(energy: FitEnergy, initial: FitState, schedule: FitSchedule, who: str,
              pose_hypotheses: Tensor | None = None) -> FitOutcome:
    """Run the global, pose-hypotheses (2D, with ``pose_hypotheses`` [H, 69] and H > 1) and full stages from
    ``initial``; ``who`` names the person in errors."""
    track = energy.track
    energy.use_priors, energy.use_speed = False, schedule.fit_scale
    if track.is_2d:
        state, stage = _global_stage_2d(energy, initial, schedule, who)
        if schedule.fit_scale:
            stage["scale_from_motion"] = _scale_from_motion(energy, state, schedule.scale_motion_rate_hz)
    else:
        state = initial.detached()
        energy.track = track.only(_global_indices(energy.body))
        stage = _minimise(energy, state, ["global_orient", "transl", *_scale(schedule)], schedule.global_iterations,
                          who, "global")
    stages = [stage]
    if track.is_2d and pose_hypotheses is not None and len(pose_hypotheses) > 1 and schedule.hypothesis_iterations:
        state, stage = _pose_hypotheses_stage(energy, state, pose_hypotheses, schedule, who)
        stages.append(stage)
    energy.track, energy.use_priors = track, True
    for step, (multiplier, robust) in enumerate(zip(schedule.pose_prior_anneal, schedule.robust_scale_anneal,
                                                    strict=True)):
        energy.pose_prior_scale, energy.robust_scale_factor = multiplier, robust
        energy.update_depth_reference(state)
        stages.append(_minimise(energy, state, _full_variables(schedule), schedule.full_iterations, who,
                                f"full_{step + 1}"))
    return FitOutcome(state.detached(), stages)


def _scale(schedule: FitSchedule) -> list[str]:
    return ["log_scale"] if schedule.fit_scale else []


def _full_variables(schedule: FitSchedule) -> list[str]:
    """The FitState fields the full and floor stages optimise: all of them but a stated shape's betas."""
    return [*([] if schedule.shape_stated else ["betas"]), "global_orient", "body_pose", "transl", *_scale(schedule)]


SCALE_CANDIDATES = np.geomspace(1e-3, 1e3, 121)  # world units per metre tried by _scale_from_motion


def _scale_from_motion(energy: FitEnergy, state: FitState, rate_hz: float) -> float:
    """In SfM units one view cannot tell a person's size from its distance: every scale s fits the
    keypoints once each frame's body is moved along its camera's rays to s times its distance.
    Across a moving camera's frames only the right s makes the person move like a person: pick
    the candidate whose pelvis path (in metres of body) has the least speed and acceleration
    energy, and rescale the state to it. The path is judged on frames about ``rate_hz`` apart (every
    stride-th frame, summed over the stride's offsets): between consecutive frames of a fast video, the
    fit's depth jitter outweighs the camera's motion in the accelerations. Returns the scale chosen (1
    when nothing tells)."""
    track, w = energy.track, energy.weights
    stride = motion_stride(track.times_s, rate_hz)
    max_gap = energy.max_gap_frames * stride  # frames: as long in time as max_gap_frames between every frame
    with torch.no_grad():
        root = energy.posed(state).joints[:, 0]  # [T, 3] at the state's scale
        centres = -torch.einsum("tji,tj->ti", track.R, track.t)  # camera centres [T, 3]
        scale_now = state.log_scale.exp()
        costs = []
        for candidate in SCALE_CANDIDATES:
            factor = candidate / scale_now
            metres = (centres + factor * (root - centres)) / candidate
            cost = 0.0
            for offset in range(stride):
                rows = slice(offset, None, stride)
                times, frame_ids = track.times_s[rows], track.frame_ids[rows]
                cost += float(speed_energy(metres[rows], times, frame_ids, w.speed_sigma_m_s, max_gap)
                              + acceleration_energy(metres[rows][:, None], times, frame_ids, w.accel_sigma_m_s2,
                                                    max_gap))
            costs.append(cost)
        costs = np.array(costs)
        if not np.isfinite(costs).all() or costs.max() - costs.min() <= 1e-9 * max(costs.max(), 1.0):
            return float(scale_now)
        best = float(SCALE_CANDIDATES[int(costs.argmin())])
        factor = best / scale_now
        # x -> c + factor (x - c) for every point of frame t, x = scale * A + transl: scale and transl change
        state.transl = centres + factor * (state.transl - centres)
        state.log_scale = torch.log(torch.as_tensor(best, dtype=state.log_scale.dtype))
    return best


def cheapest_path(data: np.ndarray, step_cost: Callable[[int], np.ndarray]) -> np.ndarray:
    """Viterbi: the hypothesis per frame minimising the sum of ``data`` [H, T] (each hypothesis' energy per
    frame) and ``step_cost(t)`` [H, H] (from each hypothesis at frame t - 1 to each at frame t). Returns [T]
    hypothesis indices."""
    hypotheses, frames = data.shape
    total, back = data[:, 0].copy(), np.zeros((frames, hypotheses), np.int64)
    for t in range(1, frames):
        candidates = total[:, None] + step_cost(t)  # [previous, current]
        back[t] = candidates.argmin(0)
        total = candidates.min(0) + data[:, t]
    chosen = np.zeros(frames, np.int64)
    chosen[-1] = int(total.argmin())
    for t in range(frames - 1, 0, -1):
        chosen[t - 1] = back[t, chosen[t]]
    return chosen


def choose_turns(data: np.ndarray, orients: np.ndarray, times_s: np.ndarray, frame_ids: np.ndarray,
                 sigma_deg_s: float, max_gap_frames: int) -> np.ndarray:
    """The hypothesis per frame minimising data + turning cost over the sequence (cheapest_path).

    data [H, T] each hypothesis' data energy per frame; orients [H, T, 3] their root orientations
    (axis-angle); turning from one frame to the next at w deg/s costs (w / sigma_deg_s)^2, between
    frames at most max_gap_frames apart (a person does not spin round between two frames; a
    profile fitted facing backwards in one frame would). Returns [T] hypothesis indices."""
    hypotheses = len(data)

    def turning(t: int) -> np.ndarray:
        if frame_ids[t] - frame_ids[t - 1] > max_gap_frames:
            return np.zeros((hypotheses, hypotheses))
        before = Rotation.from_rotvec(np.repeat(orients[:, t - 1], hypotheses, 0))
        after = Rotation.from_rotvec(np.tile(orients[:, t], (hypotheses, 1)))
        degrees = np.degrees((before.inv() * after).magnitude()).reshape(hypotheses, hypotheses)
        return (degrees / max(times_s[t] - times_s[t - 1], 1e-9) / sigma_deg_s) ** 2

    return cheapest_path(data, turning)


def hypothesis_change_cost(before: np.ndarray, after: np.ndarray, seconds: float, joint_speed_m_s: float,
                           rate_hz: float) -> np.ndarray:
    """[H, H] cost of going from each hypothesis at one frame to each at the next: the squared speed of the
    joints relative to the pelvis, ``before`` and ``after`` [H, J * 3] (metres of body), over
    ``joint_speed_m_s`` squared, with the frames ``seconds`` apart taken at least 1 / ``rate_hz`` apart.
    Rows: the hypothesis before; columns: after. Why the floor: each frame's hypotheses are fitted alone, and
    their few centimetres of jitter between the frames of a 30 fps video, read as speeds, outweighed the
    keypoints, so that the path kept was the steadiest, not the one that fits."""
    moved = after[:, None] - before[None, :]  # [after, before, J * 3]
    speed_scale = max(seconds, 1.0 / rate_hz) * joint_speed_m_s
    return (moved**2).sum(-1).T / speed_scale**2


def _pose_hypotheses_stage(energy: FitEnergy, state: FitState, poses: Tensor, schedule: FitSchedule,
                           who: str) -> tuple[FitState, dict]:
    """Each frame started from every pose of ``poses`` [H, 69] (placed as the global stage left it) and
    minimised alone against all its keypoints, with the pose prior and joint limits at their final weights
    (frames are independent here, all hypotheses at once); then per frame the hypothesis that explains the
    frame best without the body changing shape between frames (cheapest_path with hypothesis_change_cost).
    A body started standing stays standing where a crouch's thighs point at the camera (the 2D energy has no
    slope there); started crouching, it finds the crouch."""
    track, frames, hypotheses = energy.track, len(energy.track.frame_ids), len(poses)
    starts = poses.repeat_interleave(frames, 0)
    if schedule.unseen_limbs_at_rest:
        unseen = repeat_frames(unseen_limb_rotations(track.weight, energy.body.names), hypotheses)
        starts = torch.where(unseen, repeat_frames(state.body_pose, hypotheses), starts)
    batch = FitState(state.betas.clone(), repeat_frames(state.global_orient, hypotheses), starts,
                     repeat_frames(state.transl, hypotheses), state.log_scale.clone())
    energy.track, energy.use_priors, energy.frames_independent = track.repeated(hypotheses), True, True
    energy.pose_prior_scale = schedule.pose_prior_anneal[-1]
    energy.robust_scale_factor = schedule.robust_scale_anneal[-1]
    energy.update_depth_reference(batch)
    try:
        stage = _minimise(energy, batch, ["global_orient", "body_pose", "transl"], schedule.hypothesis_iterations,
                          who, "pose_hypotheses")
        with torch.no_grad():
            posed = energy.posed(batch)
            per_frame = energy.frame_energy(batch, posed.keypoints).reshape(hypotheses, frames)
            relative = (posed.joints - posed.joints[:, :1]) / batch.log_scale.exp()  # [H T, 24, 3] metres
    finally:
        energy.track, energy.frames_independent = track, False
    relative = relative.reshape(hypotheses, frames, -1).numpy()
    times, ids = track.times_s.numpy(), track.frame_ids.numpy()

    def changing(t: int) -> np.ndarray:
        if ids[t] - ids[t - 1] > energy.max_gap_frames:
            return np.zeros((hypotheses, hypotheses))
        return hypothesis_change_cost(relative[:, t - 1], relative[:, t], times[t] - times[t - 1],
                                      schedule.hypothesis_joint_speed_m_s, schedule.hypothesis_rate_hz)

    best = torch.as_tensor(cheapest_path(per_frame.numpy(), changing))
    rows = best * frames + torch.arange(frames)
    chosen = FitState(state.betas.clone(), batch.global_orient[rows].clone(), batch.body_pose[rows].clone(),
                      batch.transl[rows].clone(), state.log_scale.clone())
    stage["hypothesis_frames"] = np.bincount(best.numpy(), minlength=hypotheses).tolist()
    return chosen, stage


def unseen_limb_rotations(weight: Tensor, names: tuple[str, ...]) -> Tensor:
    """[T, 69] bool: the body_pose numbers of each frame's limbs (UNSEEN_LIMBS) none of whose end keypoints
    (those of the layout ``names``) has weight there (weight [T, K]). With ``unseen_limbs_at_rest`` the pose
    hypotheses start them at the global stage's pose: started from an arm overhead, an arm no keypoint shows
    stays overhead, as nothing in the energy pulls it down."""
    unseen = torch.zeros(weight.shape[0], 3 * len(SMPL_BODY_JOINTS), dtype=torch.bool)
    for joints, keypoints in UNSEEN_LIMBS:
        present = [names.index(k) for k in keypoints if k in names]
        if present:
            unseen[:, pose_indices(joints)] |= (weight[:, present] <= 0).all(-1, keepdim=True)
    return unseen


def _global_stage_2d(energy: FitEnergy, initial: FitState, schedule: FitSchedule, who: str) -> tuple[FitState, dict]:
    """Each frame's body turned by every yaw hypothesis about its up axis, all minimised at once
    (frames are independent here); then the sequence of hypotheses that explains the torso and head
    keypoints best without spinning round between frames (choose_turns)."""
    track, frames, hypotheses = energy.track, len(energy.track.frame_ids), len(YAW_HYPOTHESES_DEG)
    turned = []
    for yaw in YAW_HYPOTHESES_DEG:
        orient = Rotation.from_rotvec(initial.global_orient.numpy()) * Rotation.from_euler("y", yaw, degrees=True)
        turned.append(torch.as_tensor(orient.as_rotvec(), dtype=initial.transl.dtype))
    batch = FitState(initial.betas.clone(), torch.cat(turned), repeat_frames(initial.body_pose, hypotheses),
                     repeat_frames(initial.transl, hypotheses), initial.log_scale.clone())
    selected = track.only(_global_indices(energy.body))
    energy.track = selected.repeated(hypotheses)
    energy.update_depth_reference(batch)
    stage = _minimise(energy, batch, ["global_orient", "transl"], schedule.global_iterations, who, "global")
    with torch.no_grad():
        per_frame = energy.data_per_frame(batch).reshape(hypotheses, frames).numpy()
    orients = batch.global_orient.detach().reshape(hypotheses, frames, 3).numpy()
    best = torch.as_tensor(choose_turns(per_frame, orients, track.times_s.numpy(), track.frame_ids.numpy(),
                                        energy.weights.turn_rate_sigma_deg_s, energy.max_gap_frames))
    rows = best * frames + torch.arange(frames)
    state = FitState(initial.betas.clone(), batch.global_orient[rows].clone(), initial.body_pose.clone(),
                     batch.transl[rows].clone(), batch.log_scale.detach().clone())
    energy.track = track
    stage["yaw_hypotheses_chosen_deg"] = [YAW_HYPOTHESES_DEG[int(i)] for i in best]
    return state, stage


def rescale_about(state: FitState, body: KeypointBody, centre: Tensor, factor: float, ridge: float,
                  keep_shape: bool = False) -> FitState:
    """The state moved to ``factor`` times its distance from ``centre`` (a static camera's centre [3], or each
    frame's camera centre [T, 3]) and made ``factor`` times as large, so that it projects to the same pixels in
    every frame: new betas whose rest skeleton (relative to the pelvis) best matches ``factor`` times the old one
    (least squares with ``ridge`` per unit beta^2), the pelvis path scaled about the centre, orientations and pose
    kept. ``keep_shape`` (a stated shape): the betas are kept, only the pelvis path moves."""
    rest_old = body.rest_joints(state.betas)
    if keep_shape:
        betas = state.betas.clone()
    else:
        offsets = body.joint_shapedirs - body.joint_shapedirs[:1]  # [24, 3, S]: the pelvis-relative skeleton per beta
        template = body.joint_template - body.joint_template[:1]
        basis = offsets.reshape(-1, offsets.shape[-1])
        target = (factor * (rest_old - rest_old[:1]) - template).reshape(-1)
        betas = torch.linalg.solve(basis.T @ basis + ridge * torch.eye(basis.shape[1], dtype=basis.dtype),
                                   basis.T @ target)
    scale = state.log_scale.exp()
    pelvis_old = scale * rest_old[0] + state.transl  # [T, 3]
    pelvis_new = centre + factor * (pelvis_old - centre)
    transl = pelvis_new - scale * body.rest_joints(betas)[0]
    return FitState(betas, state.global_orient.clone(), state.body_pose.clone(), transl, state.log_scale.clone())


def refit_on_floor(energy: FitEnergy, state: FitState, schedule: FitSchedule, iterations: int, who: str) -> dict:
    """One more full stage at the final prior weights with ``energy.floor`` set; updates ``state``."""
    energy.use_priors = True
    energy.pose_prior_scale = schedule.pose_prior_anneal[-1]
    energy.robust_scale_factor = schedule.robust_scale_anneal[-1]
    energy.update_depth_reference(state)
    return _minimise(energy, state, _full_variables(schedule), iterations, who, "floor")
