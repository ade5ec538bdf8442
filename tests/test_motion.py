"""Motion input: file loaders, resampling, and the built-in motions checked with a tiny FK."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from glimpse.body.motion import (
    BUILTIN_MOTIONS,
    WALK_SPEED_M_S,
    BodySequence,
    builtin_motion,
    load_motion,
    resample,
)
from glimpse.errors import GlimpseError

# --- a tiny SMPL forward kinematics -------------------------------------------------------------------
#: joint names of the 24 SMPL joints (pelvis first), their parents and rough rest positions (metres;
#: y up, facing +z, left = +x, arms along +-x)
JOINTS = ("pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle",
          "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head",
          "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
          "left_hand", "right_hand")
PARENTS = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21)
HIP_X, HIP_Y, THIGH, SHIN = 0.09, -0.09, 0.38, 0.40
SHOULDER_X, SHOULDER_Y, UPPER_ARM, FOREARM = 0.17, 0.42, 0.26, 0.25
_rest = {"pelvis": (0, 0, 0), "spine1": (0, 0.11, 0), "spine2": (0, 0.24, 0), "spine3": (0, 0.30, 0),
         "neck": (0, 0.50, 0), "head": (0, 0.60, 0)}
for _side, _s in (("left", 1.0), ("right", -1.0)):
    _rest |= {f"{_side}_hip": (_s * HIP_X, HIP_Y, 0), f"{_side}_knee": (_s * HIP_X, HIP_Y - THIGH, 0),
              f"{_side}_ankle": (_s * HIP_X, HIP_Y - THIGH - SHIN, 0),
              f"{_side}_foot": (_s * HIP_X, HIP_Y - THIGH - SHIN - 0.05, 0.12),
              f"{_side}_collar": (_s * 0.07, SHOULDER_Y - 0.02, 0),
              f"{_side}_shoulder": (_s * SHOULDER_X, SHOULDER_Y, 0),
              f"{_side}_elbow": (_s * (SHOULDER_X + UPPER_ARM), SHOULDER_Y, 0),
              f"{_side}_wrist": (_s * (SHOULDER_X + UPPER_ARM + FOREARM), SHOULDER_Y, 0),
              f"{_side}_hand": (_s * (SHOULDER_X + UPPER_ARM + FOREARM + 0.08), SHOULDER_Y, 0)}
REST = np.array([_rest[name] for name in JOINTS], dtype=float)
J = {name: i for i, name in enumerate(JOINTS)}

# --- bounds -----------------------------------------------------------------------------------------
MAX_JOINT_ANGLE_DEG = 150.0
MAX_ANGULAR_SPEED_DEG_S = 720.0   # any joint or the root, between consecutive frames (fast human limbs)
MAX_ROOT_SPEED_M_S = 3.0
MAX_JOINT_SPEED_M_S = 6.0         # FK joint positions (a swinging foot peaks near 5 m/s)
MAX_FOOT_TILT_DEG = 10.0          # standing / side-stepping feet stay about level
FPS = 30.0
N_FRAMES = 90                     # 3 s


def forward_kinematics(seq: BodySequence) -> np.ndarray:
    """(T, 24, 3) world joint positions: local rotations composed down the tree, then transl."""
    rotvecs = np.concatenate([seq.global_orient, seq.body_pose], axis=1).reshape(len(seq), 24, 3)
    world_rot: list[Rotation] = []
    positions = np.zeros((len(seq), 24, 3))
    for j, parent in enumerate(PARENTS):
        local = Rotation.from_rotvec(rotvecs[:, j])
        if parent < 0:
            world_rot.append(local)
            positions[:, j] = seq.transl + REST[j]
        else:
            world_rot.append(world_rot[parent] * local)
            positions[:, j] = positions[:, parent] + world_rot[parent].apply(REST[j] - REST[parent])
    return positions


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between vectors, degrees; (..., 3) -> (...)."""
    cos = (a * b).sum(-1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def knee_angle(p: np.ndarray, side: str) -> np.ndarray:
    """Knee flexion (degrees) from FK positions: angle between thigh and shin."""
    hip, knee, ankle = (p[:, J[f"{side}_{joint}"]] for joint in ("hip", "knee", "ankle"))
    return angle_deg(knee - hip, ankle - knee)


def heading_deg(p: np.ndarray) -> np.ndarray:
    """Pelvis heading (degrees, 0 = +z, 90 = +x) from the hip line, unwrapped over frames."""
    lateral = p[:, J["left_hip"]] - p[:, J["right_hip"]]  # +x at rest
    return np.degrees(np.unwrap(np.arctan2(-lateral[:, 2], lateral[:, 0])))


def rotation_steps_deg(seq: BodySequence, wrap: bool = False) -> np.ndarray:
    """(T-1, 24) geodesic angles between consecutive frames (plus last -> first with ``wrap``)."""
    rotvecs = np.concatenate([seq.global_orient, seq.body_pose], axis=1).reshape(len(seq), 24, 3)
    following = np.roll(rotvecs, -1, axis=0) if wrap else rotvecs[1:]
    current = rotvecs if wrap else rotvecs[:-1]
    a, b = Rotation.from_rotvec(current.reshape(-1, 3)), Rotation.from_rotvec(following.reshape(-1, 3))
    return np.degrees((a.inv() * b).magnitude()).reshape(len(current), 24)


def feet_tilt_deg(p: np.ndarray) -> np.ndarray:
    """(T, 2) angle (degrees) of each ankle->foot vector from its rest direction (level, forward)."""
    tilts = []
    for side in ("left", "right"):
        rest = REST[J[f"{side}_foot"]] - REST[J[f"{side}_ankle"]]
        tilts.append(angle_deg(p[:, J[f"{side}_foot"]] - p[:, J[f"{side}_ankle"]], rest[None]))
    return np.stack(tilts, axis=1)


# --- built-in motions -------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def motions() -> dict[str, tuple[BodySequence, np.ndarray]]:
    out = {}
    for name in BUILTIN_MOTIONS:
        seq = builtin_motion(name, N_FRAMES, FPS)
        out[name] = (seq, forward_kinematics(seq))
    return out


def test_builtin_basics(motions):
    for name, (seq, p) in motions.items():
        assert len(seq) == N_FRAMES and seq.fps == FPS and seq.up_axis == "y" and seq.source == f"builtin:{name}"
        assert seq.body_pose.shape == (N_FRAMES, 69) and np.array_equal(seq.betas, np.zeros(10))
        again = builtin_motion(name, N_FRAMES, FPS)
        assert np.array_equal(again.body_pose, seq.body_pose) and np.array_equal(again.transl, seq.transl)
        assert abs(heading_deg(p)[0]) < 10.0, name  # starts facing +z
    with pytest.raises(GlimpseError, match="moonwalk"):
        builtin_motion("moonwalk", 10)


def test_builtin_joint_angles_bounded(motions):
    for name, (seq, _) in motions.items():
        angles = np.degrees(np.linalg.norm(seq.body_pose.reshape(-1, 23, 3), axis=-1))
        assert angles.max() <= MAX_JOINT_ANGLE_DEG, name


def test_builtin_continuous_and_looping(motions):
    for name, (seq, p) in motions.items():
        # wrap=True includes last -> first: playing the clip in a loop has no jump
        speed = rotation_steps_deg(seq, wrap=True).max() * FPS
        assert speed <= MAX_ANGULAR_SPEED_DEG_S, (name, speed)
        drift = np.zeros(3)
        if name == "walk":  # the walk loops up to its forward travel over the clip
            drift[2] = WALK_SPEED_M_S * N_FRAMES / FPS
        root_next = np.concatenate([seq.transl[1:], seq.transl[:1] + drift])
        assert np.linalg.norm(root_next - seq.transl, axis=1).max() * FPS <= MAX_ROOT_SPEED_M_S, name
        joints_next = np.concatenate([p[1:], p[:1] + drift])
        assert np.linalg.norm(joints_next - p, axis=2).max() * FPS <= MAX_JOINT_SPEED_M_S, name


def test_walk_swinging_foot_goes_forward(motions):
    seq, p = motions["walk"]
    for side in ("left", "right"):
        ahead = p[:, J[f"{side}_ankle"], 2] - p[:, J["pelvis"], 2]  # ankle ahead of the pelvis (m)
        knee = knee_angle(p, side)
        assert ahead.max() > 0.2 and ahead.min() < -0.2
        assert 3.0 <= knee.min() and 50.0 <= knee.max() <= 65.0  # knees flex ~5-60 degrees
        swing = int(np.argmax(knee))  # peak knee flexion: mid-swing, the foot travels forward
        assert np.gradient(ahead)[swing] > 0, side
        assert knee[int(np.argmax(ahead))] < 25.0  # the foot reaches furthest forward on a near-straight knee
        # the knee bends the shin backwards: ankle behind the knee when flexed
        assert p[swing, J[f"{side}_ankle"], 2] < p[swing, J[f"{side}_knee"], 2] - 0.1


def test_walk_arms_swing_against_legs(motions):
    _, p = motions["walk"]
    for side, other in (("left", "right"), ("right", "left")):
        arm = p[:, J[f"{side}_wrist"], 2] - p[:, J[f"{side}_shoulder"], 2]
        same_leg = p[:, J[f"{side}_ankle"], 2] - p[:, J["pelvis"], 2]
        other_leg = p[:, J[f"{other}_ankle"], 2] - p[:, J["pelvis"], 2]
        assert np.corrcoef(arm, same_leg)[0, 1] < -0.5 and np.corrcoef(arm, other_leg)[0, 1] > 0.5
        assert (p[:, J[f"{side}_wrist"], 1] < p[:, J[f"{side}_shoulder"], 1] - 0.3).all()  # arms hang down


def test_walk_root_moves_forward(motions):
    seq, p = motions["walk"]
    velocity = np.diff(seq.transl, axis=0) * FPS
    assert np.allclose(velocity[:, 2], WALK_SPEED_M_S) and np.abs(velocity[:, 0]).max() < 1e-9
    assert 0.0 < np.ptp(seq.transl[:, 1]) < 0.06  # a small bob
    assert np.abs(heading_deg(p)).max() < 15.0
    assert (p[:, J["head"], 1] > p[:, J["pelvis"], 1] + 0.5).all()  # upright


def test_wave_right_wrist_above_shoulder(motions):
    _, p = motions["wave"]
    assert (p[:, J["right_wrist"], 1] > p[:, J["right_shoulder"], 1] + 0.1).all()
    assert (p[:, J["right_wrist"], 1] > p[:, J["right_elbow"], 1]).all()  # forearm up
    assert (p[:, J["left_wrist"], 1] < p[:, J["left_shoulder"], 1] - 0.3).all()
    sideways = p[:, J["right_wrist"], 0] - p[:, J["right_elbow"], 0]
    crossings = np.count_nonzero(np.diff(np.sign(sideways - sideways.mean())))
    assert 1.5 <= crossings / 2 / (N_FRAMES / FPS) <= 2.5  # waves side to side at ~2 Hz
    ankles = p[:, [J["left_ankle"], J["right_ankle"]]]
    assert np.ptp(ankles, axis=0).max() < 0.01  # weight shifts, feet stay put
    assert feet_tilt_deg(p).max() < MAX_FOOT_TILT_DEG


def test_turn_full_circle_in_place(motions):
    seq, p = motions["turn"]
    heading = heading_deg(p)
    steps = np.diff(heading)
    assert (steps > 0).all()
    assert heading[-1] - heading[0] + steps.mean() == pytest.approx(360.0, abs=1.0)
    assert np.abs(seq.transl[:, [0, 2]]).max() < 1e-9
    for side in ("left", "right"):
        assert knee_angle(p, side).max() > 45.0  # steps, not a spin on straight legs


def test_side_step_dance(motions):
    seq, p = motions["side_step_dance"]
    assert np.ptp(seq.transl[:, 0]) == pytest.approx(0.3, abs=0.02)
    assert 0.0 < np.ptp(seq.transl[:, 1]) < 0.1
    moving_left = int(np.argmax(np.gradient(seq.transl[:, 0])))  # towards +x, the body's left
    moving_right = int(np.argmin(np.gradient(seq.transl[:, 0])))
    assert p[moving_left, J["left_ankle"], 0] - p[moving_left, J["left_hip"], 0] > 0.1  # left leg leads
    assert p[moving_right, J["right_ankle"], 0] - p[moving_right, J["right_hip"], 0] < -0.1
    assert np.ptp(p[:, J["left_wrist"], 2]) > 0.1  # arms swing
    assert feet_tilt_deg(p).max() < MAX_FOOT_TILT_DEG  # the stepping foot stays level


# --- loading files ----------------------------------------------------------------------------------

def _random_rotvecs(rng: np.random.Generator, shape: tuple[int, ...], max_angle: float = 0.5) -> np.ndarray:
    return rng.uniform(-max_angle, max_angle, shape)


def _same_rotations(a: np.ndarray, b: np.ndarray, tol: float = 1e-9) -> bool:
    ra, rb = Rotation.from_rotvec(a.reshape(-1, 3)), Rotation.from_rotvec(b.reshape(-1, 3))
    return bool((ra.inv() * rb).magnitude().max() < tol)


def _save(path: Path, arrays: dict) -> Path:
    np.savez(path, **arrays)
    return path


def test_amass_smplh_loads_and_resamples(tmp_path):
    rng = np.random.default_rng(0)
    n = 121  # 1 s at 120 fps
    poses, trans, betas = _random_rotvecs(rng, (n, 156)), rng.normal(size=(n, 3)), rng.normal(size=16)
    path = tmp_path / "amass.npz"
    np.savez(path, poses=poses, trans=trans, betas=betas, mocap_framerate=np.array(120.0),
             gender=np.array("neutral"), dmpls=np.zeros((n, 8)))
    full = load_motion(path)
    assert len(full) == n and full.fps == 120.0 and full.up_axis == "z" and full.source == str(path)
    assert np.array_equal(full.betas, betas[:10])
    assert np.array_equal(full.global_orient, poses[:, :3]) and np.array_equal(full.body_pose[:, :63], poses[:, 3:66])
    assert np.array_equal(full.body_pose[:, 63:], np.zeros((n, 6)))  # hands zeroed
    assert np.array_equal(full.transl, trans)
    seq = load_motion(path, target_fps=30)
    assert len(seq) == 31 and seq.fps == 30.0
    assert _same_rotations(seq.body_pose, full.body_pose[::4]) and np.allclose(seq.transl, trans[::4])
    assert np.array_equal(seq.body_pose[:, 63:], np.zeros((31, 6)))
    assert len(load_motion(path, target_fps=25)) == 26  # [0, 1 s] at 25 fps
    np.savez(path, poses=poses[:100], trans=trans[:100], betas=betas, mocap_frame_rate=np.array(120.0))
    assert len(load_motion(path, target_fps=30)) == 25  # 0.825 s -> frames 0..24


def test_amass_smpl72(tmp_path):
    rng = np.random.default_rng(1)
    poses = _random_rotvecs(rng, (5, 72))
    np.savez(tmp_path / "smpl.npz", poses=poses, trans=np.zeros((5, 3)), betas=np.arange(8.0),
             mocap_framerate=60)
    seq = load_motion(tmp_path / "smpl.npz")
    assert seq.fps == 60.0 and seq.up_axis == "z"
    assert np.array_equal(seq.body_pose, poses[:, 3:])  # SMPL's own hand joints are kept
    assert np.array_equal(seq.betas, np.r_[np.arange(8.0), 0, 0])  # padded to 10


def test_smplx_style(tmp_path, caplog):
    rng = np.random.default_rng(2)
    t = 6
    orient, pose = _random_rotvecs(rng, (t, 1, 3)), _random_rotvecs(rng, (t, 63))
    np.savez(tmp_path / "a.npz", global_orient=orient, body_pose=pose, transl=np.ones((t, 3)),
             betas=np.ones((1, 10)), fps=np.array(24.0), up_axis=np.array("z"))
    seq = load_motion(tmp_path / "a.npz")
    assert seq.fps == 24.0 and seq.up_axis == "z" and np.array_equal(seq.global_orient, orient[:, 0])
    assert np.array_equal(seq.body_pose[:, :63], pose) and not seq.body_pose[:, 63:].any()
    np.savez(tmp_path / "b.npz", global_orient=orient, body_pose=np.zeros((t, 69)), transl=np.ones((t, 3)),
             betas=np.ones(10))
    with caplog.at_level(logging.WARNING, logger="glimpse"):
        seq = load_motion(tmp_path / "b.npz")
    assert seq.fps == 30.0 and seq.up_axis == "y" and "assuming 30 fps" in caplog.text


def test_scene_smpl_and_body_npz(tmp_path):
    t = 4
    arrays = dict(frame_ids=np.arange(10, 10 + t), betas=np.zeros(10), global_orient=np.zeros((t, 3)),
                  body_pose=np.zeros((t, 69)), transl=np.tile([0.3, 0.0, 0.0], (t, 1)))
    np.savez(tmp_path / "smpl.npz", **arrays)
    seq = load_motion(tmp_path / "smpl.npz", target_fps=30)
    assert len(seq) == t and np.allclose(seq.transl, arrays["transl"])
    np.savez(tmp_path / "body.npz", **arrays, scale=np.array(1.0), body_model=np.array("smpl"),
             format=np.array("glimpse-body/1"))
    assert len(load_motion(tmp_path / "body.npz")) == t
    # frame ids with gaps: a grid at the gcd of the gaps, missing frames interpolated
    transl = np.array([[0, 0, 0], [2, 0, 0], [4, 0, 0], [8, 0, 0.0]])
    gapped = dict(arrays, frame_ids=np.array([0, 2, 4, 8]), transl=transl)
    seq = load_motion(_save(tmp_path / "gaps.npz", gapped))
    assert seq.fps == 15.0 and len(seq) == 5 and np.allclose(seq.transl[:, 0], [0, 2, 4, 6, 8])


def test_scene_builder_smpl_loads(tmp_path):
    builder = pytest.importorskip("scene_builder")
    root = builder.build_valid_scene(tmp_path / "scene")
    seq = load_motion(root / "humans" / "p0" / "smpl.npz")
    assert len(seq) >= 1 and seq.up_axis == "y"


def test_bad_files_name_the_file(tmp_path):
    good = dict(global_orient=np.zeros((3, 3)), body_pose=np.zeros((3, 69)), transl=np.zeros((3, 3)),
                betas=np.zeros(10))
    unknown = _save(tmp_path / "unknown.npz", {"vertices": np.zeros((3, 3))})
    with pytest.raises(GlimpseError, match=r"unknown\.npz.*'vertices'.*global_orient") as info:
        load_motion(unknown)
    assert "poses" in str(info.value)  # names both accepted layouts
    with pytest.raises(GlimpseError, match=r"nan\.npz: transl has 1 NaN"):
        load_motion(_save(tmp_path / "nan.npz", dict(good, transl=np.array([[0, 0, np.nan]] * 1 + [[0, 0, 0]] * 2))))
    with pytest.raises(GlimpseError, match=r"inf\.npz: poses has"):
        load_motion(_save(tmp_path / "inf.npz", dict(poses=np.full((2, 156), np.inf), trans=np.zeros((2, 3)))))
    with pytest.raises(GlimpseError, match=r"wide\.npz: poses must be"):
        load_motion(_save(tmp_path / "wide.npz", dict(poses=np.zeros((2, 99)), trans=np.zeros((2, 3)))))
    with pytest.raises(GlimpseError, match=r"short\.npz: body_pose must be"):
        load_motion(_save(tmp_path / "short.npz", dict(good, body_pose=np.zeros((3, 60)))))
    with pytest.raises(GlimpseError, match=r"frames\.npz: transl must be \(3, 3\)"):
        load_motion(_save(tmp_path / "frames.npz", dict(good, transl=np.zeros((2, 3)))))
    with pytest.raises(GlimpseError, match=r"ids\.npz: frame_ids"):
        load_motion(_save(tmp_path / "ids.npz", dict(good, frame_ids=np.array([0, 2, 1]))))
    with pytest.raises(GlimpseError, match=r"up\.npz: up_axis"):
        load_motion(_save(tmp_path / "up.npz", dict(good, up_axis=np.array("x"))))
    text = tmp_path / "notes.npz"
    text.write_text("not a zip")
    with pytest.raises(GlimpseError, match=r"notes\.npz"):
        load_motion(text)
    with pytest.raises(GlimpseError, match=r"missing\.npz"):
        load_motion(tmp_path / "missing.npz")


# --- resampling -------------------------------------------------------------------------------------

def _sequence(n: int, fps: float, seed: int = 3, max_angle: float = 1.5) -> BodySequence:
    rng = np.random.default_rng(seed)
    return BodySequence(np.zeros(10), _random_rotvecs(rng, (n, 3), max_angle), _random_rotvecs(rng, (n, 69), max_angle),
                        rng.normal(size=(n, 3)), fps, "y", "test")


def test_resample_same_fps_is_identity():
    seq = _sequence(7, 25.0)
    same = resample(seq, 25.0)
    for key in ("betas", "global_orient", "body_pose", "transl"):
        assert np.array_equal(getattr(same, key), getattr(seq, key))
    assert same.fps == seq.fps


def test_resample_doubling_puts_midpoints_at_slerp_halfway():
    seq = _sequence(11, 10.0)
    double = resample(seq, 20.0)
    assert len(double) == 21 and double.fps == 20.0
    rot_in = np.concatenate([seq.global_orient, seq.body_pose], axis=1).reshape(11, 24, 3)
    rot_out = np.concatenate([double.global_orient, double.body_pose], axis=1).reshape(21, 24, 3)
    assert _same_rotations(rot_out[::2], rot_in)
    for k in range(10):
        for j in range(24):
            pair = Rotation.from_rotvec(rot_in[k:k + 2, j])
            expected = Slerp([0.0, 1.0], pair)(0.5)
            got = Rotation.from_rotvec(rot_out[2 * k + 1, j])
            assert (expected.inv() * got).magnitude() < 1e-9
            # halfway: equal angles to both neighbours, half the angle between them
            to_start, to_end = (pair[0].inv() * got).magnitude(), (got.inv() * pair[1]).magnitude()
            assert to_start == pytest.approx(to_end, abs=1e-9)
            assert to_start == pytest.approx((pair[0].inv() * pair[1]).magnitude() / 2, abs=1e-9)
    assert np.allclose(double.transl[1::2], (seq.transl[:-1] + seq.transl[1:]) / 2)


def test_resample_lengths_and_edge_cases():
    assert len(resample(_sequence(100, 120.0), 30.0)) == 25
    assert len(resample(_sequence(10, 30.0), 7.0)) == 3  # 0.3 s: frames at 0, 1/7, 2/7 s
    single = resample(_sequence(1, 30.0), 60.0)
    assert len(single) == 1 and single.fps == 60.0
    with pytest.raises(GlimpseError, match="fps"):
        resample(_sequence(3, 30.0), 0.0)


def test_a_person_is_posed_at_held_out_frames_between_their_own():
    from glimpse.body.params import BodyParams

    rng = np.random.default_rng(4)
    body = BodyParams(np.array([0, 2, 6]), rng.normal(size=10), rng.normal(0, 0.4, (3, 3)), rng.normal(0, 0.2, (3, 69)),
                      rng.normal(0, 1, (3, 3)), 1.3, "free", np.zeros(3, bool))
    filled = body.with_frames_between([1, 4, 2, 7, -1])  # 2 is theirs; 7 and -1 lie outside their frames
    assert filled.frame_ids.tolist() == [0, 1, 2, 4, 6] and filled.interpolated.tolist() == [0, 1, 0, 1, 0]
    own = [0, 2, 4]
    for name in ("global_orient", "body_pose", "transl"):
        assert np.array_equal(getattr(filled, name)[own], getattr(body, name))  # their rows, exactly
    assert np.allclose(filled.transl[1], body.transl[:2].mean(0))
    assert np.allclose(filled.transl[3], body.transl[1] + 0.5 * (body.transl[2] - body.transl[1]))
    a, b = Rotation.from_rotvec(body.global_orient[0]), Rotation.from_rotvec(body.global_orient[1])
    halfway = a * Rotation.from_rotvec(0.5 * (a.inv() * b).as_rotvec())  # the shortest arc's midpoint
    assert np.allclose(Rotation.from_rotvec(filled.global_orient[1]).as_matrix(), halfway.as_matrix())
    assert filled.scale == body.scale and body.with_frames_between([7]) is body
