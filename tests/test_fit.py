"""glimpse.fit's parts: the keypoint-only body, the offline priors, the energy terms, and fits to
synthetic keypoints of known bodies (3D, and 2D through known cameras)."""

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from glimpse.body.keypoints import keypoint_map
from glimpse.body.model import BodyModel
from glimpse.body.model_file import JOINT_NAMES
from glimpse.body.motion import BUILTIN_MOTIONS, SMPL_BODY_JOINTS, builtin_motion
from glimpse.body.params import BodyParams
from glimpse.config import config_from_mapping, load_pipeline_yaml
from glimpse.errors import ConfigError, GlimpseError
from glimpse.fit.config import FitConfig
from glimpse.fit.evaluate import (body_joints, joint_errors, motion_errors, moved_onto_truth, placement_errors,
                                  scaled_about_cameras, scene_scale_errors, shape_errors)
from glimpse.fit.keypoint_body import KeypointBody
from glimpse.fit.keypoint_fit import (FitSchedule, cheapest_path, choose_turns, fit_track, hypothesis_change_cost,
                                      initial_state_2d, initial_state_3d, motion_stride, unseen_limb_rotations)
from glimpse.fit.objective import FitEnergy, Track, acceleration_energy, data_energy, speed_limit_energy
from glimpse.fit.priors import (build_pose_prior, joint_limits, mirror_body_pose, motion_poses,
                                representative_poses)
from glimpse.fixtures.scenes import FREE_BODY, intrinsics, look_at_pose

F64 = torch.float64


@pytest.fixture(scope="module")
def model():
    return BodyModel.from_file(FREE_BODY, dtype=F64)


@pytest.fixture(scope="module")
def config():
    return config_from_mapping(FitConfig, load_pipeline_yaml()["02_smpl_fit"], "pipeline.yaml")


@pytest.fixture(scope="module")
def prior(config):
    return build_pose_prior(config.pose_prior_motions, config.pose_prior_floor_deg)


@pytest.mark.parametrize("layout", ["coco17", "openpose25"])
def test_keypoint_body_equals_the_full_model(model, layout):
    kmap = keypoint_map(layout, model.data)
    body = KeypointBody(model, kmap)
    g = torch.Generator().manual_seed(3)
    betas, orient = torch.randn(10, generator=g, dtype=F64), torch.randn(4, 3, generator=g, dtype=F64)
    pose, transl = 0.3 * torch.randn(4, 69, generator=g, dtype=F64), torch.randn(4, 3, generator=g, dtype=F64)
    scale = torch.tensor(1.7, dtype=F64)
    full = model(betas[None], orient, pose, transl, scale=scale)
    fast = body(betas, orient, pose, transl, scale)
    assert torch.allclose(fast.joints, full.joints, atol=1e-12)
    assert torch.allclose(fast.keypoints, kmap(full.joints, full.vertices), atol=1e-6)  # metres


def test_size_ratio_is_the_rest_joints_spread_over_the_templates(model):
    body = KeypointBody(model, keypoint_map("coco17", model.data))
    names = [str(n) for n in model.data.extras["shape_preset_names"]]
    presets = np.asarray(model.data.extras["shape_preset_betas"], np.float64)[:, :10]

    def spread(betas):  # from the full model's rest joints (another path than the keypoint body's bases)
        rest = model(torch.as_tensor(betas)[None], torch.zeros(1, 3, dtype=F64), torch.zeros(1, 69, dtype=F64))
        joints = rest.rest_joints[0]
        return float((joints - joints.mean(0)).square().sum(-1).mean().sqrt())

    assert float(body.size_ratio(torch.zeros(10, dtype=F64))) == pytest.approx(1.0)
    for name in ("tall", "child"):
        betas = presets[names.index(name)]
        assert float(body.size_ratio(torch.as_tensor(betas))) == pytest.approx(spread(betas) / spread(np.zeros(10)))
    assert float(body.size_ratio(torch.as_tensor(presets[names.index("tall")]))) > 1.1
    assert float(body.size_ratio(torch.as_tensor(presets[names.index("child")]))) < 0.9


def test_mirroring_a_pose_swaps_sides_and_is_its_own_inverse():
    pose = np.zeros((1, 69))
    knee = SMPL_BODY_JOINTS.index("left_knee")
    pose[0, 3 * knee:3 * knee + 3] = [0.8, 0.1, -0.2]
    mirrored = mirror_body_pose(pose)
    right = SMPL_BODY_JOINTS.index("right_knee")
    assert np.allclose(mirrored[0, 3 * right:3 * right + 3], [0.8, -0.1, 0.2])
    assert np.count_nonzero(mirrored) == 3
    walk = builtin_motion("walk", 30).body_pose
    assert np.allclose(mirror_body_pose(mirror_body_pose(walk)), walk)


def test_single_gaussian_pose_prior_is_the_gaussian_of_the_motions(config):
    motions = ["walk", "turn", "wave", "side_step_dance"]  # none bends the spine forward
    prior = build_pose_prior(motions, config.pose_prior_floor_deg, mixture=False)
    poses = motion_poses(motions)
    samples = np.concatenate([poses, mirror_body_pose(poses)])
    covariance = np.cov(samples.T) + math.radians(config.pose_prior_floor_deg) ** 2 * np.eye(69)
    W = prior.whitenings[0].numpy()
    assert np.allclose(W.T @ W @ covariance, np.eye(69), atol=1e-8)
    assert np.allclose(prior.mean.numpy(), samples.mean(0))
    assert float(prior.energy(prior.mean[None])) == pytest.approx(0.0, abs=1e-12)
    # bending the spine, which no motion does, costs at least (angle / floor)^2
    odd = prior.mean.clone()
    odd[3 * SMPL_BODY_JOINTS.index("spine1")] = 1.2
    assert float(prior.energy(odd[None])) > 0.95 * (1.2 / math.radians(config.pose_prior_floor_deg)) ** 2
    assert float(prior.energy(odd[None])) > float(prior.energy(torch.as_tensor(samples)).max())


def test_mixture_pose_prior_has_one_gaussian_per_motion_and_keeps_a_crouch(config):
    motions = ["walk", "side_step_dance", "crouch"]
    prior = build_pose_prior(motions, config.pose_prior_floor_deg, mixture=True)
    assert prior.means.shape == (3, 69) and "mixture of 3" in prior.description
    for k, motion in enumerate(motions):
        poses = motion_poses([motion])
        samples = np.concatenate([poses, mirror_body_pose(poses)])
        covariance = np.cov(samples.T) + math.radians(config.pose_prior_floor_deg) ** 2 * np.eye(69)
        W = prior.whitenings[k].numpy()
        assert np.allclose(W.T @ W @ covariance, np.eye(69), atol=1e-8), motion
        assert np.allclose(prior.means[k].numpy(), samples.mean(0)), motion
    # -2 log of the equal-weight mixture density, up to a constant: checked against scipy
    from scipy.stats import multivariate_normal

    pose = torch.as_tensor(builtin_motion("crouch", 30).body_pose[13:17])  # the deepest crouch
    densities = []
    for k in range(3):
        covariance = np.linalg.inv(prior.whitenings[k].numpy().T @ prior.whitenings[k].numpy())
        densities.append(multivariate_normal(prior.means[k].numpy(), covariance).logpdf(pose.numpy()))
    reference = -2 * np.logaddexp.reduce(np.stack(densities), axis=0)
    difference = prior.energy(pose).numpy() - reference
    assert np.allclose(difference, difference[0], atol=1e-6)  # the same constant for every pose
    # a deep crouch costs, and is pulled, far less than under one Gaussian over the same motions (a blob
    # centred on neither crouching nor walking)
    single = build_pose_prior(motions, config.pose_prior_floor_deg, mixture=False)
    pulls = []
    for candidate in (prior, single):
        held = pose.clone().requires_grad_(True)
        energy = candidate.energy(held)
        pulls.append((energy.detach(), torch.autograd.grad(energy.sum(), held)[0].norm(dim=1)))
    assert (pulls[0][0] < 0.6 * pulls[1][0]).all() and (pulls[0][1] < 0.7 * pulls[1][1]).all()
    assert torch.autograd.gradcheck(prior.energy, (pose.clone().requires_grad_(True),))


def test_a_prior_mixed_over_the_legs_only_keeps_a_crouch_and_the_arms_broad_pull(config):
    """The legs' rotations under a mixture (one Gaussian per motion), the other joints under one Gaussian: the
    energy is the sum of the two parts, each equal to the prior built on its numbers alone."""
    from glimpse.fit.priors import build_parted_pose_prior, pose_indices

    motions = ["walk", "wave", "crouch"]
    legs = ("left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle", "left_foot",
            "right_foot")
    parted = build_parted_pose_prior(motions, config.pose_prior_floor_deg, legs)
    leg_index = pose_indices(legs)
    rest = np.setdiff1d(np.arange(69), leg_index)
    assert sorted(np.concatenate([p[0].numpy() for p in parted.parts]).tolist()) == list(range(69))
    pose = torch.as_tensor(builtin_motion("crouch", 30).body_pose[13:17])  # the deepest crouch
    legs_alone = build_pose_prior(motions, config.pose_prior_floor_deg, mixture=True, index=leg_index)
    rest_alone = build_pose_prior(motions, config.pose_prior_floor_deg, mixture=False, index=rest)
    assert torch.allclose(parted.energy(pose), legs_alone.energy(pose[:, leg_index]) + rest_alone.energy(pose[:, rest]))
    single = build_pose_prior(motions, config.pose_prior_floor_deg, mixture=False)
    pulls = []
    for candidate in (parted, single):
        held = pose.clone().requires_grad_(True)
        gradient = torch.autograd.grad(candidate.energy(held).sum(), held)[0]
        pulls.append(gradient[:, leg_index].norm(dim=1))
    assert (pulls[0] < 0.7 * pulls[1]).all()  # the crouching legs are pulled less
    assert torch.allclose(parted.mean, single.mean) and "left_hip" in parted.description


def test_joint_limits_accept_every_built_in_motion_and_refuse_bending_the_wrong_way():
    limits = joint_limits()
    for name in BUILTIN_MOTIONS:
        assert float(limits.energy(torch.as_tensor(builtin_motion(name, 60).body_pose)).max()) == 0.0, name
    for joint, axis_value in (("left_knee", (-0.5, 0, 0)), ("left_elbow", (0, 0.5, 0)), ("right_elbow", (0, -0.5, 0))):
        pose = torch.zeros(1, 69, dtype=F64)
        i = SMPL_BODY_JOINTS.index(joint)
        pose[0, 3 * i:3 * i + 3] = torch.tensor(axis_value)
        assert float(limits.energy(pose)) > 0.1, joint


def test_acceleration_energy_of_a_uniformly_accelerated_point():
    times = torch.tensor([0.0, 0.1, 0.3, 0.4, 0.6], dtype=F64)  # uneven spacing
    accel, sigma = 3.0, 20.0
    joints = torch.zeros(5, 24, 3, dtype=F64)
    joints[..., 1] = 0.5 * accel * times[:, None] ** 2 + 0.7 * times[:, None]
    energy = acceleration_energy(joints, times, torch.arange(5), sigma, max_gap_frames=10)
    assert float(energy) == pytest.approx(3 * 24 * (accel / sigma) ** 2, rel=1e-9)
    assert float(acceleration_energy(joints, times, torch.tensor([0, 1, 30, 31, 32]), sigma, 10)) == pytest.approx(
        1 * 24 * (accel / sigma) ** 2, rel=1e-9)  # triples across a long gap are not linked


def test_speed_limit_energy_costs_only_the_excess_over_the_limit():
    times = torch.arange(12, dtype=F64) / 32  # 32 fps: a span of 0.125 s is 4 frames
    walker = torch.zeros(12, 3, dtype=F64)
    walker[:, 0] = 1.4 * times  # walking, under the limit of 3 m/s
    assert float(speed_limit_energy(walker, times, torch.arange(12), 3.0, 0.5, 0.125, 15)) == 0.0
    jump = walker.clone()
    jump[6:, 2] += 2.0  # two metres back between frames 5 and 6: every 4-frame pair across it (2, 3, 4, 5)
    pairs = torch.arange(8)
    across = (pairs < 6) & (pairs + 4 >= 6)
    speeds = torch.sqrt(1.4**2 + (2.0 * across.to(F64) / 0.125) ** 2)
    expected = (torch.relu(speeds - 3.0) ** 2).sum() / 0.5**2
    energy = speed_limit_energy(jump, times, torch.arange(12), 3.0, 0.5, 0.125, 15)
    assert float(energy) == pytest.approx(float(expected), rel=1e-9)
    far_apart = torch.cat([torch.arange(6), torch.arange(40, 46)])  # the jump across a gap longer than 15 frames
    assert float(speed_limit_energy(jump, times, far_apart, 3.0, 0.5, 0.125, 15)) == 0.0


def test_speed_limit_energy_gradient_matches_finite_differences():
    times = torch.arange(9, dtype=F64) / 30
    points = torch.randn(9, 3, dtype=F64, generator=torch.Generator().manual_seed(0)).requires_grad_()
    energy = lambda p: speed_limit_energy(p, times, torch.arange(9), 3.0, 0.5, 0.1, 15)  # noqa: E731
    assert float(energy(points)) > 0
    assert torch.autograd.gradcheck(energy, (points,), eps=1e-6, atol=1e-5)


@pytest.mark.parametrize("bad", [{"speed_limit_m_s": -1.0}, {"speed_limit_sigma_m_s": 0.0},
                                 {"speed_limit_span_s": -0.1}])
def test_a_malformed_speed_limit_is_refused_naming_the_parameter(bad):
    raw = load_pipeline_yaml()["02_smpl_fit"]
    with pytest.raises(ConfigError, match="02_smpl_fit.weights.speed_limit"):
        config_from_mapping(FitConfig, {**raw, "weights": {**raw["weights"], **bad}}, "pipeline.yaml")
    off = {**raw, "weights": {**raw["weights"], "speed_limit_m_s": 0.0, "speed_limit_sigma_m_s": 0.0}}
    assert config_from_mapping(FitConfig, off, "pipeline.yaml").weights.speed_limit_m_s == 0.0


def test_data_energy_is_quadratic_for_small_residuals_and_bounded_for_outliers():
    weight = torch.ones(1, 2, dtype=F64)
    small = data_energy(torch.tensor([[0.001, 0.002]], dtype=F64), weight, 0.02, 0.1)
    assert float(small) == pytest.approx((0.001**2 + 0.002**2) / 0.02**2, rel=1e-3)
    huge = data_energy(torch.tensor([[1e3, 1e6]], dtype=F64), weight, 0.02, 0.1)
    assert float(huge) == pytest.approx(2 * (0.1 / 0.02) ** 2, rel=1e-5)


# ------------------------------------------------------------------------------------- synthetic fits

def _known_person(model, frames: int):
    motion = builtin_motion("walk", frames, fps=10.0)
    betas = np.linspace(-1.0, 1.0, 10)
    yaw = np.radians(35.0)
    orient = np.tile([0.0, yaw, 0.0], (frames, 1))  # turned, walking across
    transl = motion.transl @ np.array([[np.cos(yaw), 0, -np.sin(yaw)], [0, 1, 0], [np.sin(yaw), 0, np.cos(yaw)]]).T
    transl = transl + [0.3, 0.0, 3.0]
    return BodyParams(np.arange(frames), betas, orient, motion.body_pose, transl, 1.0, "free", np.zeros(frames, bool))


def _posed_keypoints(body: KeypointBody, params: BodyParams):
    """The body's joints and keypoints in every frame of ``params``."""
    with torch.no_grad():
        return body(torch.as_tensor(params.betas), torch.as_tensor(params.global_orient),
                    torch.as_tensor(params.body_pose), torch.as_tensor(params.transl),
                    torch.tensor(params.scale, dtype=F64))


def _static_view(points, eye, target):
    """A 320x240, 60-degree camera at ``eye`` looking at ``target`` over every frame of ``points`` [T, K, 3]:
    (K, R, t per frame, the points in the camera's axes, their pixels)."""
    K = intrinsics(320, 240, 60.0)
    R, t = look_at_pose(np.array(eye, float), np.array(target, float))
    Ks, Rs, ts = (torch.as_tensor(np.repeat(a[None], len(points), 0)) for a in (K, R, t))
    cam = torch.einsum("ij,tkj->tki", Rs[0], points) + ts[0]
    pixels = cam[..., :2] / cam[..., 2:] * torch.tensor([K[0, 0], K[1, 1]]) + torch.as_tensor(K[:2, 2])
    return Ks, Rs, ts, cam, pixels


def _fit(model, config, prior, track, initial, full_iterations: int = 60, pose_hypotheses=None,
         unseen_limbs_at_rest: bool = False):
    energy = FitEnergy(KeypointBody(model, keypoint_map("coco17", model.data)), track, prior, joint_limits(),
                       config.weights, config.max_interpolated_gap)
    schedule = FitSchedule(config.global_iterations, full_iterations, tuple(config.pose_prior_anneal),
                           tuple(config.robust_scale_anneal), False, config.scale_motion_rate_hz,
                           config.pose_hypothesis_iterations, config.pose_hypothesis_joint_speed_m_s,
                           config.pose_hypothesis_rate_hz, unseen_limbs_at_rest)
    return fit_track(energy, initial, schedule, "person test", pose_hypotheses)


def _as_params(outcome, frame_ids):
    s = outcome.state
    return BodyParams(frame_ids, s.betas.numpy(), s.global_orient.numpy(), s.body_pose.numpy(), s.transl.numpy(),
                      float(s.log_scale.exp()), "free", np.zeros(len(frame_ids), bool))


def _truth(params):
    return {"frame_ids": params.frame_ids, "betas": params.betas, "global_orient": params.global_orient,
            "body_pose": params.body_pose, "transl": params.transl}


def test_a_body_moved_by_a_similarity_is_moved_back_onto_the_truth(model):
    """The placement-from-truth diagnostic (bench/joint.py): a true body turned 7 degrees, 8% larger and shifted
    comes back exactly, interpolated frames moved alike; a different pose keeps its pose error."""
    truth = _known_person(model, 6)
    turn = Rotation.from_euler("xyz", [2.0, 7.0, -1.0], degrees=True)
    orient = (turn * Rotation.from_rotvec(truth.global_orient)).as_rotvec()
    shift = np.array([0.4, -0.1, 0.9])
    true_root = body_joints(model, truth.betas, truth.global_orient, truth.body_pose, truth.transl)[:, 0]
    unmoved_root = body_joints(model, truth.betas, orient, truth.body_pose, np.zeros((6, 3)), 1.08)[:, 0]
    interpolated = np.array([False, False, True, False, False, False])
    placed = BodyParams(truth.frame_ids, truth.betas, orient, truth.body_pose,
                        1.08 * turn.apply(true_root) + shift - unmoved_root, 1.08, "free", interpolated)
    assert joint_errors(model, placed, _truth(truth))["mpjpe_m"] > 0.5
    moved, move = moved_onto_truth(model, placed, _truth(truth))
    assert move.scale == pytest.approx(1 / 1.08)
    np.testing.assert_allclose(body_joints(model, moved.betas, moved.global_orient, moved.body_pose, moved.transl,
                                           moved.scale),
                               body_joints(model, truth.betas, truth.global_orient, truth.body_pose, truth.transl),
                               atol=1e-9)
    bent = replace(placed, body_pose=truth.body_pose + 0.1)
    errors = joint_errors(model, moved_onto_truth(model, bent, _truth(truth))[0], _truth(truth))
    assert errors["mpjpe_m"] == pytest.approx(errors["sequence_aligned_m"], rel=1e-6)


def test_a_body_scaled_about_the_cameras_projects_to_the_same_pixels(model):
    """The scene-scale diagnostic (bench/joint.py): each joint moves to c + s (x - c) about its frame's camera centre,
    so its direction from the camera, and with it its pixel, is unchanged; scene_scale_errors finds 1 / s back."""
    truth = _known_person(model, 6)
    centres = np.array([[0.3, 1.5, -2.5]] * 3 + [[0.5, 1.4, -2.0]] * 3)  # a camera that moved once
    scaled = scaled_about_cameras(model, truth, centres, 1.03)
    before = body_joints(model, truth.betas, truth.global_orient, truth.body_pose, truth.transl, truth.scale)
    after = body_joints(model, scaled.betas, scaled.global_orient, scaled.body_pose, scaled.transl, scaled.scale)
    np.testing.assert_allclose(after, centres[:, None] + 1.03 * (before - centres[:, None]), atol=1e-9)
    assert scaled.scale == pytest.approx(1.03 * truth.scale)
    scale, _ = scene_scale_errors(model, {"p0": scaled}, {"p0": _truth(truth)},
                                  {int(f): c for f, c in zip(truth.frame_ids, centres)})
    assert scale == pytest.approx(1 / 1.03, abs=1e-3)


def test_motion_errors_of_a_jittering_fit_against_a_standing_truth(model):
    """motion_errors against closed forms: the truth stands still (every foot planted, no acceleration or jerk);
    the fit is the truth shifted by +-e along x in alternate frames, so each joint's second difference is 4e, its
    third 8e and each foot moves 2e between frames (times fps^2, fps^3 and fps); frame 6 is missing, so only the
    runs 0-5 and 7-10 count."""
    frames, fps, e = 11, 8.0, 0.01
    ids = np.delete(np.arange(frames), 6)
    standing = BodyParams(ids, np.zeros(10), np.zeros((10, 3)), np.zeros((10, 69)), np.tile([0.0, 0.9, 3.0], (10, 1)),
                          1.0, "free", np.zeros(10, bool))
    sign = np.where(ids % 2 == 0, 1.0, -1.0)
    jittering = replace(standing, transl=standing.transl + e * sign[:, None] * [1.0, 0.0, 0.0])
    truth = _truth(standing)
    still = motion_errors(model, standing, truth, fps)
    for key in ("accel_error_m_s2", "jitter_m_s3", "foot_skate_m_s"):
        assert still[key] == pytest.approx(0.0, abs=1e-9)
    assert still["contact_pairs"] == 2 * (5 + 3)  # two feet over the pairs of frames 0-5 and 7-10
    moved = motion_errors(model, jittering, truth, fps)
    assert moved["accel_error_m_s2"] == pytest.approx(4 * e * fps ** 2)
    assert moved["jitter_m_s3"] == pytest.approx(8 * e * fps ** 3)
    assert moved["true_jitter_m_s3"] == pytest.approx(0.0, abs=1e-9)
    assert moved["foot_skate_m_s"] == pytest.approx(2 * e * fps)
    assert moved["true_foot_skate_m_s"] == pytest.approx(0.0, abs=1e-9)
    # the truth walking (the built-in walk, whose feet slide: docs/fitting.md): fewer planted pairs
    walking = _known_person(model, 10)
    assert motion_errors(model, walking, _truth(walking), 10.0)["contact_pairs"] < 2 * 9


def test_shape_errors_compare_rest_bodies_and_remove_only_their_size(model):
    """The same shape at 1.1 times the size is 10% of each vertex's distance from the root off as fitted and 0
    size aligned; another shape stays off either way; the pose never counts."""
    truth = _known_person(model, 3)
    rest = model(torch.as_tensor(truth.betas), torch.zeros(1, 3, dtype=F64), torch.zeros(1, 69, dtype=F64))
    reach = float(torch.linalg.norm(rest.vertices[0] - rest.joints[0, 0], dim=1).mean())
    larger = replace(truth, scale=1.1, body_pose=np.zeros_like(truth.body_pose))
    errors = shape_errors(model, larger, _truth(truth))
    assert errors["surface_m"] == pytest.approx(0.1 * reach, rel=1e-9)
    assert errors["surface_size_aligned_m"] < 1e-12
    other = shape_errors(model, replace(truth, betas=np.zeros(10)), _truth(truth))
    assert other["surface_size_aligned_m"] > 0.005 and other["surface_m"] >= other["surface_size_aligned_m"]


def test_the_masks_put_in_front_whoever_owns_the_overlap_of_two_skeletons():
    """front_by_masks: two upright skeletons side by side overlap in a band; the person whose mask covers the band
    is in front; masks that share it, or skeletons that do not overlap, tell nothing."""
    from glimpse.body.model_file import SMPL_PARENTS
    from glimpse.fit.evaluate import front_by_masks

    def skeleton(x: float) -> np.ndarray:  # every joint on one vertical line, the neck 60 px above the pelvis
        points = np.zeros((len(SMPL_PARENTS), 2))
        points[:, 0], points[:, 1] = x, np.linspace(40.0, 160.0, len(SMPL_PARENTS))
        points[0, 1], points[12, 1] = 140.0, 80.0
        return points

    shape = (200, 200)
    a, b = skeleton(90.0), skeleton(100.0)  # drawn 0.15 x 60 = 9 px either side: they overlap in x 91-99
    mask_a, mask_b = np.zeros(shape, bool), np.zeros(shape, bool)
    mask_a[:, 80:100] = True  # a's body covers the overlap: a is in front, b's visible part is beside it
    mask_b[:, 100:110] = True
    kwargs = {"parents": list(SMPL_PARENTS), "radius_torsos": 0.15, "min_pixels": 50, "min_share": 0.5,
              "max_minority": 0.5}
    assert front_by_masks(a, b, mask_a, mask_b, **kwargs) == 0
    assert front_by_masks(b, a, mask_b, mask_a, **kwargs) == 1
    mask_b[:, 90:100] = True  # both masks claim the overlap: no answer
    assert front_by_masks(a, b, mask_a, mask_b, **kwargs) is None
    assert front_by_masks(a, skeleton(150.0), mask_a, mask_b, **kwargs) is None  # apart: no overlap
    assert front_by_masks(a, b, np.zeros(shape, bool), np.zeros(shape, bool), **kwargs) is None  # both hidden


def test_the_scene_scale_removes_one_common_factor_about_the_camera_and_nothing_else(model):
    """scene_scale_errors: two people, each frame scaled by 1.07 about that frame's camera centre (a camera that
    moves), project to the same pixels and come back exactly; with one of them then moved 30 cm further, no
    common factor puts both back (each stays over 10 cm off), where the per-person alignment hides it."""
    frames, factor = 5, 1.07
    centres = {f: np.array([0.1 * f, 1.5, -0.2]) for f in range(frames)}
    near = _known_person(model, frames)
    far = replace(near, transl=near.transl + [1.2, 0.0, 1.5])
    c = np.stack([centres[f] for f in range(frames)])

    def scaled(person: BodyParams) -> BodyParams:
        return replace(person, transl=factor * person.transl + (1 - factor) * c, scale=factor * person.scale)

    truths = {"near": _truth(near), "far": _truth(far)}
    fitted = {"near": scaled(near), "far": scaled(far)}
    assert joint_errors(model, fitted["far"], truths["far"])["mpjpe_m"] > 0.1
    scale, errors = scene_scale_errors(model, fitted, truths, centres)
    assert scale == pytest.approx(1 / factor, rel=1e-7)
    assert max(errors.values()) < 1e-6
    off = replace(fitted["far"], transl=fitted["far"].transl + [0.0, 0.0, 0.3])
    _, errors = scene_scale_errors(model, {**fitted, "far": off}, truths, centres)
    assert min(errors.values()) > 0.1  # one factor cannot put both back: it splits the difference
    as_fitted = [joint_errors(model, person, truths[pid])["mpjpe_m"] for pid, person in {**fitted, "far": off}.items()]
    assert np.mean(list(errors.values())) <= np.mean(as_fitted)  # the best factor is never worse than none
    assert joint_errors(model, off, truths["far"])["sequence_aligned_m"] < 0.01


def test_placement_errors_count_the_depth_order_and_how_far_apart_its_misses_were(model):
    """placement_errors: two people 1.5 m apart in depth, fitted in place, agree in every frame; with the farther one
    fitted 2 m nearer in one frame the order is wrong there, and the largest miss is their true 1.5 m gap."""
    frames = 4
    centres = {f: np.zeros(3) for f in range(frames)}
    near = _known_person(model, frames)
    far = replace(near, transl=near.transl + [0.3, 0.0, 1.5])
    truths = {"near": _truth(near), "far": _truth(far)}
    placed = placement_errors(model, {"near": near, "far": far}, truths, centres)
    assert placed["depth_order_agreement"] == 1.0 and placed["depth_order_largest_miss_m"] == 0.0
    assert placed["pelvis_distance_error_m"] < 1e-9

    def first_pelvis_distance(person: BodyParams) -> float:
        joints = body_joints(model, person.betas, person.global_orient, person.body_pose, person.transl)
        return float(np.linalg.norm(joints[0, 0]))

    true_gap = first_pelvis_distance(far) - first_pelvis_distance(near)
    swapped = replace(far, transl=far.transl - np.array([[0.0, 0.0, 2.0]] + [[0.0, 0.0, 0.0]] * (frames - 1)))
    placed = placement_errors(model, {"near": near, "far": swapped}, truths, centres)
    assert placed["depth_order_agreement"] == pytest.approx(0.75)
    assert placed["depth_order_largest_miss_m"] == pytest.approx(true_gap)


def test_fit_to_clean_3d_keypoints_recovers_the_body(model, config, prior):
    truth = _known_person(model, 10)
    body = KeypointBody(model, keypoint_map("coco17", model.data))
    points = _posed_keypoints(body, truth)
    track = Track(torch.arange(10), torch.arange(10, dtype=F64) / 10, points.keypoints, torch.ones(10, 17, dtype=F64))
    outcome = _fit(model, config, prior, track, initial_state_3d(body, track, prior.mean, False))
    errors = joint_errors(model, _as_params(outcome, truth.frame_ids), _truth(truth))
    assert errors["mpjpe_m"] < 0.02, errors
    assert [s["stage"] for s in outcome.stages] == ["global", "full_1", "full_2", "full_3"]


def test_a_crouch_fitted_to_3d_keypoints_keeps_its_legs(model, config, prior):
    """A person who crouches (knees bent to 120 degrees, which the default walking-like prior never shows), 100
    frames at 33 fps, fitted to exact 3D keypoints with the stage's schedule. With the 2D fits' robust scale
    (robust_scale_3d_m = robust_scale_m = 0.1 m) the ankles, far from where the prior starts them, hardly pull
    and the fit stops with them 5.4 cm off on average (26 cm at worst); 3D keypoints get a wider one."""
    frames, fps = 100, 100 / 3
    motion = builtin_motion("crouch", frames, fps=fps)
    truth = BodyParams(np.arange(frames), np.linspace(-1.0, 1.0, 10), motion.global_orient, motion.body_pose,
                       motion.transl + [0.0, 0.0, 3.0], 1.0, "free", np.zeros(frames, bool))
    knee = 3 * SMPL_BODY_JOINTS.index("left_knee")
    assert np.degrees(truth.body_pose[:, knee]).max() > 110.0  # deep enough to test the point
    body = KeypointBody(model, keypoint_map("coco17", model.data))
    track = Track(torch.arange(frames), torch.arange(frames, dtype=F64) / fps, _posed_keypoints(body, truth).keypoints,
                  torch.ones(frames, 17, dtype=F64))
    outcome = _fit(model, config, prior, track, initial_state_3d(body, track, prior.mean, False),
                   config.full_iterations)
    fitted = _as_params(outcome, truth.frame_ids)
    ankles = [JOINT_NAMES.index(name) for name in ("left_ankle", "right_ankle")]
    ours = body_joints(model, fitted.betas, fitted.global_orient, fitted.body_pose, fitted.transl)[:, ankles]
    true = body_joints(model, truth.betas, truth.global_orient, truth.body_pose, truth.transl)[:, ankles]
    assert np.linalg.norm(ours - true, axis=-1).mean() < 0.025


def test_fit_to_clean_2d_keypoints_recovers_the_body_up_to_depth(model, config, prior):
    truth = _known_person(model, 10)
    body = KeypointBody(model, keypoint_map("coco17", model.data))
    Ks, Rs, ts, _, pixels = _static_view(_posed_keypoints(body, truth).keypoints, [0.0, 1.5, -1.0], [0.3, 1.0, 3.5])
    track = Track(torch.arange(10), torch.arange(10, dtype=F64) / 10, pixels, torch.ones(10, 17, dtype=F64),
                  Ks, Rs, ts)
    outcome = _fit(model, config, prior, track, initial_state_2d(body, track, prior.mean))
    errors = joint_errors(model, _as_params(outcome, truth.frame_ids), _truth(truth))
    assert errors["sequence_aligned_m"] < 0.05, errors
    assert errors["frame_aligned_m"] < 0.05, errors  # (as fitted, depth and body size trade off)


def test_representative_poses_start_at_the_mean_and_spread_out():
    motions = ["walk", "sit"]
    poses = representative_poses(motions, 6)
    library = motion_poses(motions)
    library = np.concatenate([library, mirror_body_pose(library)])
    assert poses.shape == (6, 69)
    assert np.allclose(poses[0], library.mean(0))
    assert all(any(np.allclose(p, q) for q in library) for p in poses[1:])  # the others are the motions' own
    gaps = [min(np.linalg.norm(poses[i] - poses[j]) for j in range(i)) for i in range(1, 6)]
    assert all(a >= b - 1e-12 for a, b in zip(gaps, gaps[1:]))  # each next one nearer the ones before
    assert np.array_equal(representative_poses(motions, 6), poses)
    assert len(representative_poses(["walk"], 10_000)) == 2 * len(motion_poses(["walk"])) + 1  # all there is


def test_cheapest_path_pays_for_changing_hypothesis():
    data = np.array([[0.0, 0.0, 5.0, 5.0], [1.0, 1.0, 0.0, 0.0]])
    free = cheapest_path(data, lambda t: np.zeros((2, 2)))
    assert free.tolist() == [0, 0, 1, 1]
    change = np.array([[0.0, 20.0], [20.0, 0.0]])
    assert cheapest_path(data, lambda t: change).tolist() == [1, 1, 1, 1]  # switching costs more than it gains


def test_the_hypothesis_path_follows_the_keypoints_not_the_steadiest_fit_in_a_fast_video(config):
    """Two hypotheses per frame of a 30 fps video: one fits every frame's keypoints better but, fitted frame by
    frame, its joints jitter by a few centimetres; the other is a steady wrong pose. Read as speeds over a
    thirtieth of a second, the jitter cost more than the keypoints gained, and the wrong pose was kept for
    whole seconds (the full-size demo's second person, after another person hid it for three frames)."""
    rng = np.random.default_rng(0)
    frames, fps, joints = 30, 30.0, 24
    rest = rng.normal(0.0, 0.3, joints * 3)
    fitting = rest + rng.normal(0.0, 0.03, (frames, joints * 3))  # 3 cm of jitter per coordinate
    steady = np.repeat((rest + 0.1)[None], frames, 0)  # 10 cm off, the same every frame
    relative = np.stack([fitting, steady])  # [H, T, J * 3]
    data = np.stack([np.full(frames, 20.0), np.full(frames, 60.0)])  # the fitting one explains each frame better
    speed, rate = config.pose_hypothesis_joint_speed_m_s, config.pose_hypothesis_rate_hz

    def cost(rate_hz):
        return lambda t: hypothesis_change_cost(relative[:, t - 1], relative[:, t], 1.0 / fps, speed, rate_hz)

    assert cheapest_path(data, cost(fps)).tolist() == [1] * frames  # judged at the frame rate: the steady one
    assert cheapest_path(data, cost(rate)).tolist() == [0] * frames
    # At or below the rate, the cost is the joints' speed over the frames' own interval, as before.
    slow = hypothesis_change_cost(relative[:, 0], relative[:, 1], 2.0 / rate, speed, rate)
    moved = relative[:, None, 1] - relative[None, :, 0]
    assert np.allclose(slow, (moved**2).sum(-1).T / (2.0 / rate * speed) ** 2)


def test_a_crouch_facing_the_camera_is_found_from_2d_keypoints_with_pose_hypotheses(model, config):
    """A person crouching towards the camera (as in the crouch fixture): its thighs point at the camera, so a
    body started standing sits on a saddle of the 2D energy (bending towards the camera moves no keypoint at
    first) and the fit keeps the legs nearly straight, even with a prior that knows crouching (the stage's
    default, a mixture over the built-in motions). Started from poses spread over the prior's motions as
    well, the fit finds the crouch."""
    frames, fps = 24, 8.0
    motion = builtin_motion("crouch", frames, fps=fps)
    yaw = np.radians(200.0)  # nearly facing the camera (the motion faces +z, the camera looks along +z)
    turn = np.array([[np.cos(yaw), 0.0, np.sin(yaw)], [0.0, 1.0, 0.0], [-np.sin(yaw), 0.0, np.cos(yaw)]])
    truth = BodyParams(np.arange(frames), np.zeros(10), np.tile([0.0, yaw, 0.0], (frames, 1)), motion.body_pose,
                       motion.transl @ turn.T + [0.3, 0.0, 2.0], 1.0, "free", np.zeros(frames, bool))
    body = KeypointBody(model, keypoint_map("coco17", model.data))
    Ks, Rs, ts, _, pixels = _static_view(_posed_keypoints(body, truth).keypoints, [0.0, 1.5, -2.5], [0.0, 1.0, 1.8])
    track = Track(torch.arange(frames), torch.arange(frames, dtype=F64) / fps, pixels,
                  torch.ones(frames, 17, dtype=F64), Ks, Rs, ts)
    prior = build_pose_prior(config.pose_prior_motions, config.pose_prior_floor_deg, mixture=config.pose_prior_mixture)
    assert "crouch" in config.pose_prior_motions and config.pose_hypotheses > 1
    spread = representative_poses(config.pose_prior_motions, config.pose_hypotheses)[1:]
    hypotheses = torch.cat([prior.mean[None], torch.as_tensor(spread)])
    knee = JOINT_NAMES.index("left_knee")
    deepest = int(np.argmax(np.abs(motion.body_pose[:, 3 * (knee - 1)])))
    errors, knee_error_deg = {}, {}
    for name, poses in (("standing only", None), ("hypotheses", hypotheses)):
        outcome = _fit(model, config, prior, track, initial_state_2d(body, track, prior.mean), 60, poses)
        fitted = _as_params(outcome, truth.frame_ids)
        errors[name] = joint_errors(model, fitted, _truth(truth))["frame_aligned_m"]
        ours, true = (body_joints(model, p.betas, p.global_orient, p.body_pose, p.transl)[deepest]
                      for p in (fitted, truth))
        angle = lambda j: np.degrees(np.arccos(np.dot(j[1] - j[4], j[7] - j[4])  # noqa: E731
                                               / np.linalg.norm(j[1] - j[4]) / np.linalg.norm(j[7] - j[4])))
        knee_error_deg[name] = abs(angle(ours) - angle(true))  # hip-knee-ankle, left leg
        assert ("pose_hypotheses" in [s["stage"] for s in outcome.stages]) == (poses is not None)
    assert errors["hypotheses"] < 0.3 * errors["standing only"], errors
    assert knee_error_deg["hypotheses"] < 10.0 < knee_error_deg["standing only"], knee_error_deg


def test_a_fit_that_diverges_stops_with_a_clear_message(model, config, prior):
    body = KeypointBody(model, keypoint_map("coco17", model.data))
    points = torch.zeros(3, 17, 3, dtype=F64)
    points[:, :, 0] = torch.linspace(0, 1, 17)
    points[:, :, 1] = torch.linspace(0, 1, 17) ** 2
    track = Track(torch.arange(3), torch.arange(3, dtype=F64), points, torch.ones(3, 17, dtype=F64))
    initial = initial_state_3d(body, track, prior.mean, False)
    initial.transl[1, 0] = float("nan")
    with pytest.raises(GlimpseError, match=r"person test: the fit diverged .* in its global stage"):
        _fit(model, config, prior, track, initial)


def test_choosing_turns_prefers_a_steady_heading_over_a_slightly_better_flip():
    frames, yaw = 5, np.radians([0.0, 90.0, 180.0, 270.0])
    orients = np.zeros((4, frames, 3))
    orients[:, :, 1] = yaw[:, None]
    data = np.full((4, frames), 100.0)
    data[0] = 10.0
    data[2, 2] = 8.0  # frame 2 alone would rather face backwards
    times, ids = np.arange(frames) / 30.0, np.arange(frames)
    assert choose_turns(data, orients, times, ids, 180.0, 15).tolist() == [0, 0, 0, 0, 0]
    data = np.full((4, frames), 5000.0)  # nothing else fits: the first two frames face forwards ...
    data[0, :2], data[2, 2:] = 10.0, 1.0  # ... and the rest backwards: one turn, at frame 2
    assert choose_turns(data, orients, times, ids, 180.0, 15).tolist() == [0, 0, 2, 2, 2]
    far_apart = np.array([0, 1, 40, 41, 42])  # a long gap: no link, each side decides alone
    data[2, :2], data[0, 2:], data[2, 2:] = 100.0, 10.0, 8.0
    data[[1, 3]] = 100.0
    assert choose_turns(data, orients, far_apart / 30.0, far_apart, 180.0, 15).tolist() == [0, 0, 2, 2, 2]


def test_a_moving_camera_in_sfm_units_gives_the_person_scale(model, config, prior):
    """The same scene in a world scaled by 0.4 (SfM units): pixels are unchanged, and the camera's
    motion around the person fixes its size in world units, so the fitted scale is about 0.4."""
    frames, units_per_metre = 12, 0.4
    truth = _known_person(model, frames)
    truth = BodyParams(truth.frame_ids, np.zeros(10), truth.global_orient, truth.body_pose, truth.transl, 1.0,
                       "free", truth.interpolated)
    body = KeypointBody(model, keypoint_map("coco17", model.data))
    points = _posed_keypoints(body, truth)
    K = intrinsics(320, 240, 60.0)
    Rs, ts, pixels = [], [], []
    for f in range(frames):
        centre = truth.transl[f] + [0.0, 0.3, 0.0]
        angle = np.radians(-60.0 + 120.0 * f / (frames - 1))
        R, t = look_at_pose(centre + 3.0 * np.array([np.sin(angle), 0.2, np.cos(angle)]), centre)
        cam = points.keypoints[f].numpy() @ R.T + t
        pixels.append(cam[:, :2] / cam[:, 2:] * [K[0, 0], K[1, 1]] + K[:2, 2])
        Rs.append(R)
        ts.append(units_per_metre * t)  # the same camera in a world scaled by units_per_metre
    track = Track(torch.arange(frames), torch.arange(frames, dtype=F64) / 10, torch.as_tensor(np.stack(pixels)),
                  torch.ones(frames, 17, dtype=F64), torch.as_tensor(np.repeat(K[None], frames, 0)),
                  torch.as_tensor(np.stack(Rs)), torch.as_tensor(np.stack(ts)))
    energy = FitEnergy(body, track, prior, joint_limits(), config.weights, config.max_interpolated_gap)
    schedule = FitSchedule(config.global_iterations, 60, tuple(config.pose_prior_anneal),
                           tuple(config.robust_scale_anneal), True, config.scale_motion_rate_hz)
    outcome = fit_track(energy, initial_state_2d(body, track, prior.mean), schedule, "person test")
    assert float(outcome.state.log_scale.exp()) == pytest.approx(units_per_metre, rel=0.1)
    assert outcome.stages[0]["scale_from_motion"] == pytest.approx(units_per_metre, rel=0.25)


# ------------------------------------------------------------------------------------- metric 3D keypoints

def _child_seen_from(model, frames: int):
    """A child (the free body's child preset) walking, seen by a static camera: (truth, body, track with pixels
    and the exact metric relative3d in the camera's axes)."""
    names = [str(n) for n in model.data.extras["shape_preset_names"]]
    child = np.asarray(model.data.extras["shape_preset_betas"], np.float64)[names.index("child")][:10]
    base = _known_person(model, frames)
    truth = BodyParams(base.frame_ids, child, base.global_orient, base.body_pose, base.transl, 1.0, "free",
                       base.interpolated)
    body = KeypointBody(model, keypoint_map("coco17", model.data))
    Ks, Rs, ts, cam, pixels = _static_view(_posed_keypoints(body, truth).keypoints, [0.0, 1.5, -1.0], [0.3, 1.0, 3.5])
    relative = cam - cam[:, [11, 12]].mean(1, keepdim=True)  # COCO-17 hips
    ones = torch.ones(frames, 17, dtype=F64)
    return truth, body, Track(torch.arange(frames), torch.arange(frames, dtype=F64) / 10, pixels, ones, Ks, Rs, ts,
                              relative, ones)


def test_metric_3d_keypoints_fix_a_childs_size_and_distance(model, config, prior):
    """From pixels alone a child is fitted at the shape prior's adult size, too far away; with the metric 3D
    keypoints (exact here, their size trusted) the body's size, and so its distance, come out near, with no
    alignment."""
    from dataclasses import replace

    from glimpse.fit.objective import relative3d_residual_m

    truth, body, track = _child_seen_from(model, 10)
    exact = _posed_keypoints(body, truth).keypoints
    one, two = torch.tensor(1.0, dtype=F64), torch.tensor(2.0, dtype=F64)
    assert float(relative3d_residual_m(exact, track, [11, 12], one).max()) < 1e-9
    assert float(relative3d_residual_m(exact, track, [11, 12], two).max()) > 0.1
    assert float(relative3d_residual_m(exact, track, [11, 12], two, model_size=False).max()) < 1e-9  # size free
    metric_size = replace(config, weights=replace(config.weights, relative3d_size="model"))
    errors = {}
    for name, used in (("pixels", replace(track, relative3d=None, relative3d_weight=None)), ("metric", track)):
        outcome = _fit(model, metric_size, prior, used, initial_state_2d(body, used, prior.mean))
        errors[name] = joint_errors(model, _as_params(outcome, truth.frame_ids), _truth(truth))["mpjpe_m"]
    assert errors["metric"] < 0.15 and errors["pixels"] > 5 * errors["metric"], errors


def test_metric_keypoints_are_turned_onto_the_persons_viewing_ray():
    from glimpse.fit.stage import onto_viewing_rays

    K = np.array([[100.0, 0.0, 50.0], [0.0, 100.0, 40.0], [0.0, 0.0, 1.0]])
    relative = np.array([[[0.0, 0.0, 1.0], [0.0, -0.5, 0.0]]])  # one point 1 m behind the hips, one 0.5 m up
    weight = np.ones((1, 2))
    centred = onto_viewing_rays(relative, np.array([[[50.0, 40.0], [50.0, 40.0]]]), weight, K[None])
    np.testing.assert_allclose(centred, relative)  # a person on the optical axis: nothing to turn
    right = onto_viewing_rays(relative, np.array([[[150.0, 40.0], [150.0, 40.0]]]), weight, K[None])
    np.testing.assert_allclose(right[0, 0], np.array([1.0, 0.0, 1.0]) / np.sqrt(2), atol=1e-12)  # along the ray
    np.testing.assert_allclose(right[0, 1], [0.0, -0.5, 0.0], atol=1e-12)  # up stays up (turned about y)
    unseen = onto_viewing_rays(relative, np.zeros((1, 2, 2)), np.zeros((1, 2)), K[None])
    np.testing.assert_allclose(unseen, relative)


def test_the_scales_motion_test_samples_the_path_at_about_its_rate():
    """At 33 fps consecutive frames are too close for the pelvis path's motion to tell the scale (a 2D fit's depth
    jitter swamps it): the path is judged on every 4th frame; at 8 fps on every frame."""
    assert motion_stride(torch.arange(100, dtype=F64) / 33.0, 8.0) == 4
    assert motion_stride(torch.arange(24, dtype=F64) / 8.0, 8.0) == 1
    assert motion_stride(torch.tensor([0.0, 0.05, 0.1, 1.0], dtype=F64), 5.0) == 4  # the median step: 20 fps
    assert motion_stride(torch.zeros(1, dtype=F64), 8.0) == 1


def test_the_size_prior_holds_a_2d_fit_to_the_templates_size_and_places_it_by_that(model, config, prior):
    """A taller-than-average body seen in 2D: with the size prior off the fit takes the size its keypoints'
    proportions say (exact keypoints here: near the truth); with it on, the body is held to the template's size
    (within about size_sigma) and so stands nearer the camera, as far as a template-sized body making the same
    pixels would."""
    names = [str(n) for n in model.data.extras["shape_preset_names"]]
    tall = np.asarray(model.data.extras["shape_preset_betas"], np.float64)[names.index("man")][:10]
    truth = replace(_known_person(model, 10), betas=tall)
    body = KeypointBody(model, keypoint_map("coco17", model.data))
    true_size = float(body.size_ratio(torch.as_tensor(tall)))
    assert true_size > 1.04
    Ks, Rs, ts, cam, pixels = _static_view(_posed_keypoints(body, truth).keypoints, [0.0, 1.5, -1.0],
                                           [0.3, 1.0, 3.5])
    track = Track(torch.arange(10), torch.arange(10, dtype=F64) / 10, pixels, torch.ones(10, 17, dtype=F64),
                  Ks, Rs, ts)
    sizes, depths = {}, {}
    for sigma in (0.0, 0.01):
        held = replace(config, weights=replace(config.weights, size_sigma=sigma))
        outcome = _fit(model, held, prior, track, initial_state_2d(body, track, prior.mean))
        sizes[sigma] = float(body.size_ratio(outcome.state.betas))
        fitted = _posed_keypoints(body, _as_params(outcome, truth.frame_ids)).keypoints
        depths[sigma] = float(((fitted @ Rs[0].T + ts[0])[..., 2].mean() / cam[..., 2].mean()))
    assert sizes[0.0] > 1.03, sizes
    assert abs(sizes[0.01] - 1.0) < 0.02, sizes
    assert depths[0.01] == pytest.approx(depths[0.0] * sizes[0.01] / sizes[0.0], rel=0.03), (depths, sizes)


def test_the_limbs_no_keypoint_shows_are_found_per_frame():
    """unseen_limb_rotations: the body_pose numbers of an arm or leg none of whose end keypoints is seen in a
    frame, in that frame only."""
    names = keypoint_map("coco17", BodyModel.from_file(FREE_BODY, dtype=F64).data).names
    weight = torch.ones(3, 17, dtype=F64)
    weight[1, [names.index("left_elbow"), names.index("left_wrist")]] = 0.0  # frame 1: the left arm unseen
    weight[2, names.index("left_wrist")] = 0.0  # frame 2: its elbow still seen
    unseen = unseen_limb_rotations(weight, names)
    arm = [JOINT_NAMES.index(j) for j in ("left_collar", "left_shoulder", "left_elbow", "left_wrist", "left_hand")]
    expected = torch.zeros(3, 69, dtype=torch.bool)
    for joint in arm:
        expected[1, 3 * (joint - 1):3 * joint] = True
    assert torch.equal(unseen, expected)


def test_an_arm_the_keypoints_never_show_is_not_raised_by_a_pose_hypothesis(model, config):
    """A walker in profile whose far arm no keypoint shows (a detector's far side): a hypothesis started
    with an arm raised (reach, wave) explains the seen keypoints as well, and nothing pulls the unseen arm
    down again (without unseen_limbs_at_rest this walker's far arm ends overhead). With it the hypotheses
    leave such a limb where the global stage put it (the prior's mean)."""
    frames, fps = 24, 8.0
    motion = builtin_motion("walk", frames, fps=fps)
    yaw = np.radians(90.0)  # walking across the view, the left side away from the camera
    turn = np.array([[np.cos(yaw), 0.0, np.sin(yaw)], [0.0, 1.0, 0.0], [-np.sin(yaw), 0.0, np.cos(yaw)]])
    truth = BodyParams(np.arange(frames), np.zeros(10), np.tile([0.0, yaw, 0.0], (frames, 1)), motion.body_pose,
                       motion.transl @ turn.T + [-0.6, 0.0, 3.0], 1.0, "free", np.zeros(frames, bool))
    body = KeypointBody(model, keypoint_map("coco17", model.data))
    Ks, Rs, ts, _, pixels = _static_view(_posed_keypoints(body, truth).keypoints, [0.0, 1.5, -1.0], [0.0, 1.0, 3.0])
    weight = torch.ones(frames, 17, dtype=F64)
    weight[:, [body.names.index("left_elbow"), body.names.index("left_wrist")]] = 0.0
    track = Track(torch.arange(frames), torch.arange(frames, dtype=F64) / fps, pixels, weight, Ks, Rs, ts)
    prior = build_pose_prior(config.pose_prior_motions, config.pose_prior_floor_deg, mixture=config.pose_prior_mixture)
    spread = representative_poses(config.pose_prior_motions, config.pose_hypotheses)[1:]
    hypotheses = torch.cat([prior.mean[None], torch.as_tensor(spread)])
    outcome = _fit(model, config, prior, track, initial_state_2d(body, track, prior.mean), 60, hypotheses, True)
    fitted = _as_params(outcome, truth.frame_ids)
    joints = body_joints(model, fitted.betas, fitted.global_orient, fitted.body_pose, fitted.transl)
    wrist, shoulder = JOINT_NAMES.index("left_wrist"), JOINT_NAMES.index("left_shoulder")
    assert (joints[:, wrist, 1] < joints[:, shoulder, 1] - 0.3).all(), joints[:, wrist, 1] - joints[:, shoulder, 1]
