"""Motion input: SMPL body-parameter sequences from files, resampling, built-in motions.

A :class:`BodySequence` holds smplx-style SMPL parameters over time: ``betas (10,)``,
``global_orient (T, 3)`` and ``body_pose (T, 69)`` as axis-angle vectors (radians; 23
body joints in SMPL order, local rotations in the parent frame of the rest T-pose),
``transl (T, 3)`` in metres, sampled at ``fps`` frames per second (frame k at k / fps s).

Sources: AMASS-style ``.npz`` (``poses``, ``trans``, ...; z up), smplx-style ``.npz``
(``global_orient``, ``body_pose``, ``transl``, ...; y up unless stated, e.g. a scene's
``smpl.npz`` or a stage's ``body.npz``), and :func:`builtin_motion` (procedural, y up,
facing +z, left = +x).
"""

from __future__ import annotations

import logging
import math
import zipfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from glimpse.errors import GlimpseError

__all__ = ["BUILTIN_MOTIONS", "SMPL_BODY_JOINTS", "BodySequence", "builtin_motion", "interpolate_pose_sequence",
           "load_motion", "resample"]

log = logging.getLogger("glimpse")

SMPL_BODY_JOINTS = (
    "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle", "right_ankle",
    "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head", "left_shoulder",
    "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hand", "right_hand")
_JOINT = {name: i for i, name in enumerate(SMPL_BODY_JOINTS)}
N_BETAS = 10
N_BODY_JOINTS = len(SMPL_BODY_JOINTS)          # 23
BODY_POSE_DIM = 3 * N_BODY_JOINTS             # 69
HANDLESS_POSE_DIM = BODY_POSE_DIM - 6         # 63: the 21 joints shared by SMPL, SMPL-H and SMPL-X
SMPLH_POSES_DIM = 156                         # AMASS SMPL-H: 3 root + 63 body + 90 finger values
SMPL_POSES_DIM = 72                           # plain SMPL: 3 root + 69 body values
DEFAULT_FPS = 30.0                            # assumed (with a warning) when a file states no rate
UP_AXES = ("y", "z")
FPS_KEYS = ("fps", "mocap_framerate", "mocap_frame_rate")
AMASS_KEYS = ("poses", "trans", "betas", "mocap_framerate")
SMPLX_KEYS = ("global_orient", "body_pose", "transl", "betas")
SMPLX_OPTIONAL_KEYS = ("fps", "frame_ids", "up_axis", "scale")
_FRAME_TOLERANCE = 1e-9                       # in frames: a time this close to a whole frame counts as it


@dataclass(frozen=True)
class BodySequence:
    """SMPL parameters over T frames (see the module docstring for units and frames)."""

    betas: np.ndarray          # (10,)
    global_orient: np.ndarray  # (T, 3) axis-angle, radians
    body_pose: np.ndarray      # (T, 69) axis-angle, radians, 23 joints in SMPL order
    transl: np.ndarray         # (T, 3) metres
    fps: float                 # frames per second
    up_axis: str               # "y" (SMPL canonical, built-in motions) or "z" (AMASS)
    source: str                # file path or "builtin:<name>"

    def __post_init__(self) -> None:
        n = len(self.global_orient)
        shapes = (self.betas.shape, self.global_orient.shape, self.body_pose.shape, self.transl.shape)
        valid_rate = math.isfinite(self.fps) and self.fps > 0 and self.up_axis in UP_AXES
        if shapes != ((N_BETAS,), (n, 3), (n, BODY_POSE_DIM), (n, 3)) or n < 1 or not valid_rate:
            raise ValueError(f"BodySequence {self.source}: expected betas (10,), global_orient (T, 3), body_pose "
                             f"(T, 69), transl (T, 3), T >= 1, fps > 0, up_axis in {UP_AXES}; got {shapes}, "
                             f"fps={self.fps}, up_axis={self.up_axis!r}")

    def __len__(self) -> int:
        return len(self.global_orient)


# --- reading files ----------------------------------------------------------------------------------

def load_motion(path: str | Path, target_fps: float | None = None) -> BodySequence:
    """Read an AMASS-style or smplx-style ``.npz`` motion; resample to ``target_fps`` if given.

    AMASS-style: ``poses`` (N, 156) SMPL-H or (N, 72) SMPL, ``trans`` (N, 3), ``betas``,
    ``mocap_framerate``; up axis z. Of SMPL-H poses the root and 21 body joints are kept and
    SMPL's two hand joints set to zero (SMPL-H's joints 22+ are fingers); SMPL poses are kept whole.
    smplx-style: ``global_orient`` (T, 3), ``body_pose`` (T, 69) or (T, 63) (hands padded with
    zeros), ``transl`` (T, 3), ``betas``, optional ``fps``, ``frame_ids`` (gaps are filled by
    interpolation at the gcd of the gaps), ``up_axis`` ("y" default). ``betas`` keeps its first 10
    values, padded with zeros. Without a frame rate, 30 fps is assumed and a warning logged.
    Raises GlimpseError naming the file for anything unreadable, unknown or non-finite.
    """
    path = Path(path)
    try:
        data = np.load(path, allow_pickle=False)
        if not isinstance(data, np.lib.npyio.NpzFile):
            raise GlimpseError(f"{path}: not a .npz archive (a single array); expected a motion .npz "
                               f"with keys {AMASS_KEYS} (AMASS) or {SMPLX_KEYS} (smplx)")
        with data:
            keys = set(data.files)
            if {"poses", "trans"} <= keys:
                sequence = _read_amass(path, data, keys)
            elif set(SMPLX_KEYS[:3]) <= keys:
                sequence = _read_smplx(path, data, keys)
            else:
                raise GlimpseError(
                    f"{path}: not a motion file; found keys {sorted(keys)}; expected AMASS-style "
                    f"{list(AMASS_KEYS)} or smplx-style {list(SMPLX_KEYS)} (optional {list(SMPLX_OPTIONAL_KEYS)})")
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise GlimpseError(f"{path}: cannot read as a .npz motion file ({exc})") from exc
    return sequence if target_fps is None else resample(sequence, target_fps)


def _array(path: Path, data, key: str) -> np.ndarray:
    """``data[key]`` as finite float64, or GlimpseError."""
    try:
        values = np.asarray(data[key], dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise GlimpseError(f"{path}: {key} is not numeric ({exc})") from exc
    bad = ~np.isfinite(values)
    if bad.any():
        raise GlimpseError(f"{path}: {key} has {int(bad.sum())} NaN or infinite value(s)")
    return values


def _shaped(path: Path, data, key: str, width: int, frames: int) -> np.ndarray:
    """``data[key]`` reshaped to (frames, width) (accepts e.g. (T, 1, 3) or (T, 23, 3))."""
    values = _array(path, data, key)
    if values.ndim < 2 or values.shape[0] != frames or values[0].size != width:
        raise GlimpseError(f"{path}: {key} must be ({frames}, {width}); found shape {values.shape}")
    return values.reshape(frames, width)


def _betas(path: Path, data, keys: set[str]) -> np.ndarray:
    """First 10 shape coefficients, zero-padded; zeros (with a warning) when absent."""
    out = np.zeros(N_BETAS)
    if "betas" not in keys:
        log.warning("%s: no betas; using the mean shape (zeros)", path)
        return out
    values = _array(path, data, "betas")
    values = values[0] if values.ndim == 2 and values.shape[0] == 1 else values
    if values.ndim != 1:
        raise GlimpseError(f"{path}: betas must be (K,) or (1, K); found shape {values.shape}")
    count = min(N_BETAS, len(values))
    out[:count] = values[:count]
    return out


def _fps(path: Path, data, keys: set[str]) -> float:
    """The file's frame rate (``fps`` / ``mocap_framerate`` / ``mocap_frame_rate``), else 30."""
    for key in FPS_KEYS:
        if key in keys:
            values = _array(path, data, key)
            if values.size != 1 or values.item() <= 0:
                raise GlimpseError(f"{path}: {key} must be one positive number; found {values.ravel()[:4]}")
            return float(values.item())
    log.warning("%s: no frame rate (%s); assuming %g fps", path, " / ".join(FPS_KEYS), DEFAULT_FPS)
    return DEFAULT_FPS


def _read_amass(path: Path, data, keys: set[str]) -> BodySequence:
    poses = _array(path, data, "poses")
    if poses.ndim != 2 or poses.shape[1] not in (SMPLH_POSES_DIM, SMPL_POSES_DIM) or len(poses) < 1:
        raise GlimpseError(f"{path}: poses must be (N, {SMPLH_POSES_DIM}) (SMPL-H) or (N, {SMPL_POSES_DIM}) "
                           f"(SMPL) with N >= 1; found shape {poses.shape}")
    body_pose = np.zeros((len(poses), BODY_POSE_DIM))
    kept = BODY_POSE_DIM if poses.shape[1] == SMPL_POSES_DIM else HANDLESS_POSE_DIM
    body_pose[:, :kept] = poses[:, 3:3 + kept]
    return BodySequence(_betas(path, data, keys), poses[:, :3].copy(), body_pose,
                        _shaped(path, data, "trans", 3, len(poses)), _fps(path, data, keys), "z", str(path))


def _read_smplx(path: Path, data, keys: set[str]) -> BodySequence:
    orient = _array(path, data, "global_orient")
    frames = len(orient) if orient.ndim >= 1 else 0
    if frames < 1:
        raise GlimpseError(f"{path}: global_orient must be (T, 3) with T >= 1; found shape {orient.shape}")
    global_orient = _shaped(path, data, "global_orient", 3, frames)
    pose = _array(path, data, "body_pose")
    width = pose[0].size if pose.ndim >= 2 and len(pose) == frames else -1
    if width not in (BODY_POSE_DIM, HANDLESS_POSE_DIM):
        raise GlimpseError(f"{path}: body_pose must be ({frames}, {BODY_POSE_DIM}) or ({frames}, "
                           f"{HANDLESS_POSE_DIM}) (no hands); found shape {pose.shape}")
    body_pose = np.zeros((frames, BODY_POSE_DIM))
    body_pose[:, :width] = pose.reshape(frames, width)
    up_axis = str(np.asarray(data["up_axis"]).item()) if "up_axis" in keys else "y"
    if up_axis not in UP_AXES:
        raise GlimpseError(f"{path}: up_axis must be one of {UP_AXES}; found {up_axis!r}")
    if "scale" in keys and not np.allclose(_array(path, data, "scale"), 1.0):
        log.warning("%s: body scale %s is not part of a motion and is ignored", path, data["scale"])
    sequence = BodySequence(_betas(path, data, keys), global_orient, body_pose,
                            _shaped(path, data, "transl", 3, frames), _fps(path, data, keys), up_axis, str(path))
    return _fill_frame_gaps(path, sequence, _array(path, data, "frame_ids")) if "frame_ids" in keys else sequence


def _fill_frame_gaps(path: Path, sequence: BodySequence, ids: np.ndarray) -> BodySequence:
    """Frames ``ids`` (strictly increasing integers) onto a uniform grid: its step is the gcd g
    of the gaps (rate fps / g); frames missing from it are interpolated."""
    if ids.shape != (len(sequence),) or not np.all(np.mod(ids, 1) == 0) or np.any(np.diff(ids) <= 0):
        raise GlimpseError(f"{path}: frame_ids must be ({len(sequence)},) strictly increasing integers; "
                           f"found shape {ids.shape}, first values {ids.ravel()[:5]}")
    offsets = (ids - ids[0]).astype(np.int64)
    step = int(np.gcd.reduce(np.diff(offsets))) if len(offsets) > 1 else 1
    grid = np.arange(offsets[-1] // step + 1)
    fps = sequence.fps / step
    if len(grid) == len(sequence):
        return replace(sequence, fps=fps)
    log.info("%s: interpolating %d missing frame(s) between frame ids", path, len(grid) - len(sequence))
    return replace(sequence, fps=fps, **_interpolate(sequence, offsets / step / fps, grid / fps))


# --- resampling ---------------------------------------------------------------------------------------

def resample(sequence: BodySequence, fps: float) -> BodySequence:
    """``sequence`` at ``fps``: frame k at time k / fps, over the same span [0, (N - 1) / fps_in].

    Rotations (root and every joint) are slerped between the neighbouring input frames,
    translations interpolated linearly; the last frame is the last whole one in the span.
    The same rate returns the input unchanged.
    """
    if not (math.isfinite(fps) and fps > 0):
        raise GlimpseError(f"resample {sequence.source}: fps must be a positive number; got {fps}")
    if fps == sequence.fps:
        return sequence
    span_frames = (len(sequence) - 1) / sequence.fps * fps
    times = np.arange(int(math.floor(span_frames + _FRAME_TOLERANCE)) + 1) / fps
    return replace(sequence, fps=float(fps),
                   **_interpolate(sequence, np.arange(len(sequence)) / sequence.fps, times))


def _interpolate(sequence: BodySequence, times_in: np.ndarray, times_out: np.ndarray) -> dict:
    """Rotations slerped and translations lerped from samples at ``times_in`` (s, increasing)
    to ``times_out`` (s, inside their span). Returns global_orient, body_pose, transl arrays."""
    return interpolate_pose_sequence(times_in, sequence.global_orient, sequence.body_pose, sequence.transl,
                                     times_out)


def interpolate_pose_sequence(times_in: np.ndarray, global_orient: np.ndarray, body_pose: np.ndarray,
                              transl: np.ndarray, times_out: np.ndarray) -> dict[str, np.ndarray]:
    """Body parameters sampled at ``times_in`` (increasing) at ``times_out`` (inside their span; any
    unit): every joint rotation slerped along the shortest arc, translations lerped.
    global_orient [N, 3], body_pose [N, 69], transl [N, 3] -> the same keys with M = len(times_out) rows."""
    n_in, n_out, joints = len(times_in), len(times_out), N_BODY_JOINTS + 1
    if n_in == 1:
        return {"global_orient": np.repeat(global_orient, n_out, 0), "body_pose": np.repeat(body_pose, n_out, 0),
                "transl": np.repeat(transl, n_out, 0)}
    lower = np.clip(np.searchsorted(times_in, times_out, side="right") - 1, 0, n_in - 2)
    alpha = np.clip((times_out - times_in[lower]) / (times_in[lower + 1] - times_in[lower]), 0.0, 1.0)
    rotvecs = np.concatenate([global_orient, body_pose], axis=1).reshape(n_in, joints, 3)
    start = Rotation.from_rotvec(rotvecs[lower].reshape(-1, 3))
    end = Rotation.from_rotvec(rotvecs[lower + 1].reshape(-1, 3))
    step = (start.inv() * end).as_rotvec() * np.repeat(alpha, joints)[:, None]  # shortest arc, scaled
    rotations = (start * Rotation.from_rotvec(step)).as_rotvec().reshape(n_out, 3 * joints)
    lerped = (1 - alpha)[:, None] * transl[lower] + alpha[:, None] * transl[lower + 1]
    return {"global_orient": rotations[:, :3], "body_pose": rotations[:, 3:], "transl": lerped}


# --- built-in motions ---------------------------------------------------------------------------------
# Angles in degrees, anatomical sense (flexion = limb forward, abduction = limb away from the midline).
T_POSE_ARM_ABDUCTION_DEG = 90.0   # the rest pose holds the arms horizontal
ARM_AT_SIDE_ABDUCTION_DEG = 15.0
KNEE_STANDING_DEG = 5.0
LEG_LENGTH_M = 0.8                # hip to ankle, an average adult
WALK_CYCLE_S = 1.1
WALK_SPEED_M_S = 1.2
WALK_BOB_M = 0.02
WALK_HIP_FLEX_DEG = 25.0          # +-, left hip = WALK_HIP_FLEX_DEG * sin(phase)
WALK_KNEE_SWING_DEG = 60.0        # peak, when the swinging thigh passes the vertical
WALK_KNEE_STANCE_DEG = 15.0       # loading-response bend after heel strike
WALK_KNEE_STANCE_PHASE = 0.4      # cycles after the swing peak (heel strike at 0.25)
WALK_SWING_SHARPNESS = 3          # exponents of the raised-cosine bumps (larger = narrower)
WALK_STANCE_SHARPNESS = 8
WALK_ANKLE_DEG = 10.0             # plantarflexion at push-off, dorsiflexion at heel strike
WALK_ARM_SWING_DEG = 20.0
WALK_ELBOW_DEG = 15.0             # plus up to WALK_ELBOW_SWING_DEG with the arm forward
WALK_ELBOW_SWING_DEG = 10.0
WALK_PELVIS_YAW_DEG = 5.0         # pelvis turns with the forward leg ...
WALK_TORSO_YAW_DEG = 5.0          # ... the thorax the other way; the head keeps looking ahead
TURN_STEP_CYCLE_S = 1.0
TURN_TOTAL_DEG = 360.0
TURN_HIP_LIFT_DEG = 35.0
TURN_KNEE_LIFT_DEG = 60.0
TURN_ANKLE_LIFT_DEG = 10.0
TURN_ARM_SWING_DEG = 10.0
TURN_ELBOW_DEG = 20.0
TURN_BOB_M = 0.02
WAVE_HZ = 2.0
WAVE_SHOULDER_ABDUCTION_DEG = 120.0
WAVE_SHOULDER_TWIST_DEG = -90.0   # external rotation: the elbow then bends the forearm upwards
WAVE_ELBOW_DEG = 60.0             # forearm vertical; +- WAVE_ELBOW_SWING_DEG side to side
WAVE_ELBOW_SWING_DEG = 30.0
WAVE_OTHER_ELBOW_DEG = 10.0
WAVE_SHIFT_CYCLE_S = 4.0
WAVE_SHIFT_M = 0.03               # +- sideways weight shift, feet kept in place
DANCE_CYCLE_S = 1.6               # one step left and one right
DANCE_SWAY_M = 0.3                # root travel along x, peak to peak
DANCE_HIP_ABDUCTION_DEG = 20.0    # the leading leg
DANCE_STEP_KNEE_DEG = 20.0        # extra knee lift of the leading leg
DANCE_KNEE_DEG = 10.0             # plus DANCE_KNEE_BOUNCE_DEG at the end of each step
DANCE_KNEE_BOUNCE_DEG = 25.0
DANCE_BOUNCE_M = 0.04
DANCE_ARM_ABDUCTION_DEG = 30.0
DANCE_ARM_SWING_DEG = 30.0
DANCE_ELBOW_DEG = 70.0
CROUCH_HIP_FLEX_DEG = 95.0        # deepest crouch (mid-clip); standing at the start and the end
CROUCH_KNEE_DEG = 120.0
CROUCH_TORSO_LEAN_DEG = 30.0      # forward, over the three spine joints
CROUCH_ARMS_UP_DEG = 170.0        # shoulder abduction standing (arms raised overhead, out to the sides) ...
CROUCH_ARMS_FORWARD_DEG = 80.0    # ... shoulder flexion in the crouch (arms at the sides swung forward, for balance)
CROUCH_ELBOW_DEG = 10.0
SIT_HIP_FLEX_DEG = 90.0           # seated (thighs level, shins upright) through the middle of the clip
SIT_KNEE_DEG = 90.0
SIT_TORSO_LEAN_DEG = 10.0
SIT_ARM_FLEX_DEG = 35.0           # hands resting on the thighs
SIT_ELBOW_DEG = 50.0
SIT_HOLD = 1.6                    # the sitting depth profile is clipped at 1 / this of its peak: a plateau
REACH_CYCLE_S = 1.5               # one reach with each arm
REACH_ABDUCTION_DEG = 165.0       # the reaching arm, overhead
REACH_SIDE_BEND_DEG = 10.0        # the trunk leans towards the reaching arm
BUILTIN_MOTIONS: tuple[str, ...] = ("walk", "turn", "wave", "side_step_dance", "crouch", "sit", "reach")
_MIRROR = np.array([1.0, -1.0, -1.0])  # a left-side rotation vector -> the right side's (x -> -x)


def builtin_motion(name: str, n_frames: int, fps: float = 30.0) -> BodySequence:
    """A procedural motion of ``n_frames`` at ``fps`` (SMPL canonical frame: y up, facing +z).

    walk: gait cycle ~1.1 s, root forward along +z at 1.2 m/s; turn: stepping in place while
    the root turns 360 degrees about +y (towards the left) over the clip; wave: right arm raised,
    forearm waving side to side at 2 Hz; side_step_dance: stepping left and right along x;
    crouch: from standing with the arms overhead down into a deep crouch (arms forward) and back
    up once over the clip, the feet kept in place; sit: sitting down (on a seat the motion does not
    show), seated through the middle of the clip, standing up; reach: standing, each arm in turn
    reaching up overhead.
    Cycle lengths are stretched to a whole number in ``n_frames / fps`` so frame ``n_frames``
    would equal frame 0 (the walk moved forward): the clip loops (for clips at least half a
    cycle long). Deterministic; betas are zero.
    """
    if name not in BUILTIN_MOTIONS:
        raise GlimpseError(f"unknown built-in motion {name!r}; choose one of {BUILTIN_MOTIONS}")
    if n_frames < 1 or not (math.isfinite(fps) and fps > 0):
        raise GlimpseError(f"builtin motion {name}: need n_frames >= 1 and fps > 0; got {n_frames}, {fps}")
    time = np.arange(n_frames) / fps
    pose = np.zeros((n_frames, N_BODY_JOINTS, 3))
    motion = {"walk": _walk, "turn": _turn, "wave": _wave, "side_step_dance": _side_step_dance,
              "crouch": _crouch, "sit": _sit, "reach": _reach}[name]
    global_orient, transl = motion(pose, time, n_frames / fps)
    return BodySequence(np.zeros(N_BETAS), global_orient, pose.reshape(n_frames, BODY_POSE_DIM), transl,
                        float(fps), "y", f"builtin:{name}")


def _phase(time: np.ndarray, duration: float, period: float) -> np.ndarray:
    """2 pi * cycles done at ``time``, a whole number of cycles in ``duration`` (>= half a period)."""
    cycles = round(duration / period)
    return 2 * np.pi * time * (cycles / duration if cycles >= 1 else 1 / period)


def _bump(phase: np.ndarray, sharpness: int) -> np.ndarray:
    """Smooth periodic bump: 1 at phase 0, 0 at +-pi."""
    return ((1 + np.cos(phase)) / 2) ** sharpness


def _chain(frames: int, *factors: tuple[str, np.ndarray | float]) -> np.ndarray:
    """(frames, 3) rotation vectors of ``R_1 R_2 ...`` for factors (axis "x"/"y"/"z", degrees);
    the last factor acts first."""
    result = Rotation.identity(frames)
    for axis, degrees in factors:
        rotvec = np.zeros((frames, 3))
        rotvec[:, "xyz".index(axis)] = np.radians(np.broadcast_to(degrees, (frames,)))
        result = result * Rotation.from_rotvec(rotvec)
    return result.as_rotvec()


def _set(pose: np.ndarray, side: str, joint: str, rotvec: np.ndarray) -> None:
    """Write a left-side-convention rotation to ``side``'s joint, mirrored for the right."""
    pose[:, _JOINT[f"{side}_{joint}"]] = rotvec if side == "left" else rotvec * _MIRROR


def _leg(pose, side, hip_flex, knee_flex, ankle_plantar=0.0, hip_abduction=0.0) -> None:
    """SMPL signs: hip flexion -x, abduction +z (left); knee flexion +x; plantarflexion +x.
    The ankle undoes the abduction so the foot stays level."""
    frames = len(pose)
    _set(pose, side, "hip", _chain(frames, ("x", -np.asarray(hip_flex)), ("z", hip_abduction)))
    _set(pose, side, "knee", _chain(frames, ("x", knee_flex)))
    _set(pose, side, "ankle", _chain(frames, ("x", ankle_plantar), ("z", -np.asarray(hip_abduction))))


def _arm(pose, side, flex, abduction, elbow_flex, twist=0.0) -> None:
    """Shoulder: twist about the arm (x), then abduction from the T-pose (+z raises the left arm),
    then flexion (-x swings it forward); elbow flexion -y (left) brings the forearm forward."""
    frames = len(pose)
    lift = np.asarray(abduction) - T_POSE_ARM_ABDUCTION_DEG
    _set(pose, side, "shoulder", _chain(frames, ("x", -np.asarray(flex)), ("z", lift), ("x", twist)))
    _set(pose, side, "elbow", _chain(frames, ("y", -np.asarray(elbow_flex))))


def _yaw(frames: int, degrees) -> np.ndarray:
    """Rotation about +y: positive turns the body from +z towards +x (its left)."""
    return _chain(frames, ("y", degrees))


def _walk(pose, time, duration):
    """Phase 0: the left thigh passes the vertical swinging forward (its knee bent most)."""
    phase = _phase(time, duration, WALK_CYCLE_S)
    for side, leg_phase in (("left", phase), ("right", phase + np.pi)):
        knee = (KNEE_STANDING_DEG + (WALK_KNEE_SWING_DEG - KNEE_STANDING_DEG) * _bump(leg_phase, WALK_SWING_SHARPNESS)
                + WALK_KNEE_STANCE_DEG * _bump(leg_phase - 2 * np.pi * WALK_KNEE_STANCE_PHASE, WALK_STANCE_SHARPNESS))
        _leg(pose, side, WALK_HIP_FLEX_DEG * np.sin(leg_phase), knee, -WALK_ANKLE_DEG * np.sin(leg_phase))
        forward = -np.sin(leg_phase)  # the arm swings with the other leg
        _arm(pose, side, WALK_ARM_SWING_DEG * forward, ARM_AT_SIDE_ABDUCTION_DEG,
             WALK_ELBOW_DEG + WALK_ELBOW_SWING_DEG * (1 + forward) / 2)
    frames = len(pose)
    for joint in ("spine1", "spine2", "spine3"):
        pose[:, _JOINT[joint]] = _yaw(frames, (WALK_PELVIS_YAW_DEG + WALK_TORSO_YAW_DEG) / 3 * np.sin(phase))
    pose[:, _JOINT["neck"]] = _yaw(frames, -WALK_TORSO_YAW_DEG * np.sin(phase))
    transl = np.stack([np.zeros(frames), WALK_BOB_M * np.cos(2 * phase), WALK_SPEED_M_S * time], axis=1)
    return _yaw(frames, -WALK_PELVIS_YAW_DEG * np.sin(phase)), transl


def _turn(pose, time, duration):
    """Marching in place (left knee up in the first half-cycle) while the root yaws 360 degrees."""
    phase = _phase(time, duration, TURN_STEP_CYCLE_S)
    lifts = {"left": np.maximum(0.0, np.sin(phase)) ** 2, "right": np.maximum(0.0, -np.sin(phase)) ** 2}
    for side, other in (("left", "right"), ("right", "left")):
        lift = lifts[side]
        _leg(pose, side, TURN_HIP_LIFT_DEG * lift, KNEE_STANDING_DEG + TURN_KNEE_LIFT_DEG * lift,
             TURN_ANKLE_LIFT_DEG * lift)
        _arm(pose, side, TURN_ARM_SWING_DEG * (lifts[other] - lift), ARM_AT_SIDE_ABDUCTION_DEG, TURN_ELBOW_DEG)
    bob, frames = TURN_BOB_M * (lifts["left"] + lifts["right"]), len(pose)
    transl = np.stack([np.zeros(frames), bob, np.zeros(frames)], axis=1)
    return _yaw(frames, TURN_TOTAL_DEG * time / duration), transl


def _wave(pose, time, duration):
    """Standing; the right forearm up, swinging side to side about the elbow; slow weight shift along x."""
    shift = WAVE_SHIFT_M * np.sin(_phase(time, duration, WAVE_SHIFT_CYCLE_S))
    tilt = -np.degrees(np.arcsin(shift / LEG_LENGTH_M))  # both legs lean so the feet stay put
    _leg(pose, "left", 0.0, KNEE_STANDING_DEG, hip_abduction=tilt)
    _leg(pose, "right", 0.0, KNEE_STANDING_DEG, hip_abduction=-tilt)
    _arm(pose, "left", 0.0, ARM_AT_SIDE_ABDUCTION_DEG, WAVE_OTHER_ELBOW_DEG)
    wave = np.sin(_phase(time, duration, 1.0 / WAVE_HZ))
    _arm(pose, "right", 0.0, WAVE_SHOULDER_ABDUCTION_DEG, WAVE_ELBOW_DEG + WAVE_ELBOW_SWING_DEG * wave,
         WAVE_SHOULDER_TWIST_DEG)
    return np.zeros((len(pose), 3)), np.stack([shift, np.zeros_like(shift), np.zeros_like(shift)], axis=1)


def _side_step_dance(pose, time, duration):
    """Root swings along x; the leg on the side it moves to leads (abducts), knees dip at each step's end."""
    phase = _phase(time, duration, DANCE_CYCLE_S)
    bounce = (1 - np.cos(2 * phase)) / 2  # 1 at the end of each step
    for side, sign in (("left", 1.0), ("right", -1.0)):
        lead = np.maximum(0.0, sign * np.cos(phase)) ** 2  # this leg leads while the root moves its way
        knee = DANCE_KNEE_DEG + DANCE_KNEE_BOUNCE_DEG * bounce + DANCE_STEP_KNEE_DEG * lead
        _leg(pose, side, knee / 2, knee, -knee / 2, DANCE_HIP_ABDUCTION_DEG * lead)  # hip + ankle = knee: foot level
        _arm(pose, side, sign * DANCE_ARM_SWING_DEG * np.sin(phase), DANCE_ARM_ABDUCTION_DEG, DANCE_ELBOW_DEG)
    frames = len(pose)
    transl = np.stack([DANCE_SWAY_M / 2 * np.sin(phase), -DANCE_BOUNCE_M * bounce, np.zeros(frames)], axis=1)
    return np.zeros((frames, 3)), transl


def _crouch(pose, time, duration):
    """Depth q = 0 (standing, arms overhead) -> 1 (crouching, arms forward) -> 0 over the clip."""
    depth = (1 - np.cos(2 * np.pi * time / duration)) / 2
    for side in ("left", "right"):
        _arm(pose, side, CROUCH_ARMS_FORWARD_DEG * depth,
             CROUCH_ARMS_UP_DEG + (ARM_AT_SIDE_ABDUCTION_DEG - CROUCH_ARMS_UP_DEG) * depth, CROUCH_ELBOW_DEG)
    return _lower_body(pose, depth, CROUCH_HIP_FLEX_DEG, CROUCH_KNEE_DEG, CROUCH_TORSO_LEAN_DEG)


def _sit(pose, time, duration):
    """Standing -> seated (a plateau through the middle of the clip) -> standing; hands on the thighs."""
    depth = np.minimum(1.0, SIT_HOLD * (1 - np.cos(2 * np.pi * time / duration)) / 2)
    for side in ("left", "right"):
        _arm(pose, side, SIT_ARM_FLEX_DEG * depth, ARM_AT_SIDE_ABDUCTION_DEG, SIT_ELBOW_DEG * depth)
    return _lower_body(pose, depth, SIT_HIP_FLEX_DEG, SIT_KNEE_DEG, SIT_TORSO_LEAN_DEG)


def _lower_body(pose, depth, hip_deg, knee_deg, lean_deg):
    """Hips and knees bent by ``depth`` (0..1) of hip_deg and knee_deg, the trunk leaning forward by
    lean_deg (over the three spine joints). The shin leans forward by knee - hip flexion and the ankle
    bends by as much (the foot stays flat); the root drops and moves back so that the ankles stay put
    (thigh and shin LEG_LENGTH_M / 2 each). Returns (global_orient, transl)."""
    hip, knee = hip_deg * depth, KNEE_STANDING_DEG + (knee_deg - KNEE_STANDING_DEG) * depth
    shin_lean = knee - hip
    for side in ("left", "right"):
        _leg(pose, side, hip, knee, -shin_lean)
    frames = len(pose)
    for joint in ("spine1", "spine2", "spine3"):
        pose[:, _JOINT[joint]] = _chain(frames, ("x", lean_deg / 3 * depth))
    segment = LEG_LENGTH_M / 2
    hip_r, shin_r, standing = np.radians(hip), np.radians(shin_lean), np.radians(KNEE_STANDING_DEG)
    height = segment * (np.cos(hip_r) + np.cos(shin_r)) - segment * (1 + np.cos(standing))
    back = -segment * (np.sin(hip_r) - np.sin(shin_r)) + segment * np.sin(standing)
    return np.zeros((frames, 3)), np.stack([np.zeros(frames), height, back], axis=1)


def _reach(pose, time, duration):
    """Standing; the left arm reaches up overhead while the right is down, then the other way round;
    the trunk leans towards the reaching arm."""
    phase = _phase(time, duration, REACH_CYCLE_S)
    frames = len(pose)
    for side, lift in (("left", np.maximum(0.0, np.sin(phase)) ** 2), ("right", np.maximum(0.0, -np.sin(phase)) ** 2)):
        _leg(pose, side, 0.0, KNEE_STANDING_DEG)
        _arm(pose, side, 0.0, ARM_AT_SIDE_ABDUCTION_DEG + (REACH_ABDUCTION_DEG - ARM_AT_SIDE_ABDUCTION_DEG) * lift,
             CROUCH_ELBOW_DEG)
    bend = REACH_SIDE_BEND_DEG * np.sin(phase)  # -z about the spine leans the trunk to its left (+x)
    for joint in ("spine1", "spine2", "spine3"):
        pose[:, _JOINT[joint]] = _chain(frames, ("z", -bend / 3))
    return np.zeros((frames, 3)), np.zeros((frames, 3))
