"""The silhouette term of 2D fits (glimpse.fit.silhouette): surface points posed as the body model poses its
vertices, the masks' distance field and outline, the term's gradient, and what it does to a fit: one to noisy
keypoints brought nearer the truth by masks drawn by the mesh z-buffer."""

import numpy as np
import pytest
import torch

from glimpse.body.keypoints import keypoint_map
from glimpse.body.model import BodyModel
from glimpse.body.model_file import JOINT_NAMES
from glimpse.body.motion import builtin_motion
from glimpse.body.params import BodyParams
from glimpse.config import config_from_mapping, load_pipeline_yaml
from glimpse.errors import ConfigError
from glimpse.fit.config import FitConfig
from glimpse.fit.evaluate import body_joints
from glimpse.fit.keypoint_body import KeypointBody
from glimpse.fit.keypoint_fit import FitSchedule, fit_track, initial_state_2d, mean_shape_keypoints
from glimpse.fit.objective import FitEnergy, FitState, SilhouetteTerm, Track
from glimpse.fit.priors import build_pose_prior, joint_limits
from glimpse.fit.sampling import farthest_point_samples
from glimpse.fit.silhouette import SurfaceBody, linked_keypoints, outline_points, sample_outside_px, silhouette_evidence
from glimpse.fixtures.scenes import intrinsics, look_at_pose
from glimpse.render.mesh_raster import rasterize_triangles

from tests.test_fit import config, model  # noqa: F401 (the body model and stage 02's parameters, as fixtures)

F64 = torch.float64
WIDTH, HEIGHT = 320, 240


@pytest.mark.parametrize("bad", [{"weight": 0.0}, {"noise_m": -0.01}, {"clothing_m": -0.01}, {"rate_hz": 0.0},
                                 {"surface_points": 0}, {"max_side_px": 0}])
def test_a_malformed_silhouette_parameter_is_refused_naming_it(bad):
    raw = load_pipeline_yaml()["02_smpl_fit"]
    with pytest.raises(ConfigError, match=f"02_smpl_fit.silhouette.{next(iter(bad))}"):
        config_from_mapping(FitConfig, {**raw, "silhouette": {**raw["silhouette"], **bad}}, "pipeline.yaml")


def test_surface_points_pose_as_the_full_model(model):
    indices = farthest_point_samples(model.v_template.numpy(), 300)
    surface = SurfaceBody(model, indices)
    motion = builtin_motion("crouch", 3, fps=10.0)
    rng = np.random.default_rng(0)
    betas, orient = torch.as_tensor(rng.normal(0, 1, 10)), torch.as_tensor(rng.normal(0, 0.5, (3, 3)))
    pose, transl = torch.as_tensor(motion.body_pose), torch.as_tensor(rng.normal(0, 1, (3, 3)))
    scale = torch.tensor(1.3, dtype=F64)
    expected = model(betas, orient, pose, transl, scale=scale).vertices[:, indices]
    torch.testing.assert_close(surface(betas, orient, pose, transl, scale), expected, rtol=0, atol=1e-10)


def test_farthest_point_samples_spread_over_the_points():
    line = np.stack([np.arange(101.0), np.zeros(101), np.zeros(101)], 1)
    assert farthest_point_samples(line, 3).tolist() == [0, 100, 50]
    assert len(set(farthest_point_samples(line, 20).tolist())) == 20
    assert len(farthest_point_samples(line, 500)) == 101


def _disc(width: int, height: int, centre: tuple[float, float], radius: float) -> np.ndarray:
    ys, xs = np.mgrid[:height, :width]
    return (xs - centre[0]) ** 2 + (ys - centre[1]) ** 2 <= radius**2


@pytest.mark.parametrize("max_side_px, tolerance_px", [(200, 0.6), (60, 2.5)])
def test_the_distance_outside_a_disc_mask_and_its_outline(max_side_px, tolerance_px):
    own, other = _disc(120, 100, (50, 40), 20), _disc(120, 100, (100, 80), 8)
    evidence = silhouette_evidence(np.array([0]), [own], [other], 1.0, max_side_px, 50, F64)
    points = torch.tensor([[[50.0, 40.0], [80.0, 40.0], [50.0, 5.0], [100.0, 80.0], [100.0, 65.0]]], dtype=F64)
    distance = sample_outside_px(evidence, points)[0].numpy()
    expected = [0.0, 10.0, 15.0, 0.0, 7.0]  # inside; 10 and 15 px beyond the disc; on the other mask; 7 px from it
    np.testing.assert_allclose(distance, expected, atol=tolerance_px)
    outline = evidence.edges_px[0][evidence.edge_weight[0] > 0].numpy()
    radii = np.linalg.norm(outline - [50.0, 40.0], axis=1)
    assert len(outline) == 50 and radii.min() > 20 - tolerance_px - 1 and radii.max() < 20 + tolerance_px
    assert len(outline_points(own, 10_000)) < own.sum() / 4  # the outline, not the interior


def _heavy_walker(model: BodyModel, frames: int) -> BodyParams:
    presets = np.asarray(model.data.extras["shape_preset_betas"], np.float64)
    heavy = presets[[str(n) for n in model.data.extras["shape_preset_names"]].index("heavy")][:10]
    motion = builtin_motion("walk", frames, fps=10.0)
    yaw = np.radians(30.0)
    turn = np.array([[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]])
    orient = np.tile([0.0, yaw, 0.0], (frames, 1))
    transl = motion.transl @ turn.T + [0.0, 0.0, 3.5]
    return BodyParams(np.arange(frames), heavy, orient, motion.body_pose, transl, 1.0, "free",
                      np.zeros(frames, bool))


def _seen(model: BodyModel, body: KeypointBody, truth: BodyParams):
    """Exact COCO-17 pixels and the body's masks (mesh z-buffer) from a 320x240 camera at eye height."""
    K = intrinsics(WIDTH, HEIGHT, 55.0)
    R, t = look_at_pose(np.array([0.0, 1.4, -1.5]), np.array([0.0, 0.9, 3.5]))
    frames = len(truth.frame_ids)
    with torch.no_grad():
        out = model(torch.as_tensor(truth.betas), torch.as_tensor(truth.global_orient),
                    torch.as_tensor(truth.body_pose), torch.as_tensor(truth.transl))
        keypoints = body(torch.as_tensor(truth.betas), torch.as_tensor(truth.global_orient),
                         torch.as_tensor(truth.body_pose), torch.as_tensor(truth.transl),
                         torch.ones((), dtype=F64)).keypoints
    masks = [rasterize_triangles(v @ R.T + t, model.faces.numpy(), K, WIDTH, HEIGHT).face >= 0
             for v in out.vertices.numpy()]
    cam = keypoints.numpy() @ R.T + t
    pixels = cam[..., :2] / cam[..., 2:] * [K[0, 0], K[1, 1]] + K[:2, 2]
    Ks, Rs, ts = (torch.as_tensor(np.repeat(a[None], frames, 0)) for a in (K, R, t))
    track = Track(torch.arange(frames), torch.arange(frames, dtype=F64) / 10, torch.as_tensor(pixels),
                  torch.ones(frames, 17, dtype=F64), Ks, Rs, ts)
    return track, masks


def _term(model: BodyModel, body: KeypointBody, config: FitConfig, track: Track, masks: list,
          points: int) -> SilhouetteTerm:
    c = config.silhouette
    surface = SurfaceBody(model, farthest_point_samples(model.v_template.numpy(), points))
    rows = np.arange(len(masks))
    evidence = silhouette_evidence(rows, masks, [np.zeros_like(m) for m in masks], 1.0, c.max_side_px,
                                   c.outline_pixels, F64)
    rest, _ = mean_shape_keypoints(body, torch.zeros(69, dtype=F64))
    links = torch.as_tensor(linked_keypoints(surface.template.numpy(), rest, c.linked_keypoints))
    return SilhouetteTerm(surface, evidence, links, c.weight, c.noise_m, c.robust_m,
                          0.5 * surface.spacing_m() + c.clothing_m)


def test_the_silhouette_terms_gradient_matches_finite_differences(model, config):
    body = KeypointBody(model, keypoint_map("coco17", model.data))
    truth = _heavy_walker(model, 2)
    track, masks = _seen(model, body, truth)
    term = _term(model, body, config, track, masks, 200)
    state = FitState(torch.zeros(10, dtype=F64), torch.as_tensor(truth.global_orient),
                     torch.as_tensor(truth.body_pose), torch.as_tensor(truth.transl) + torch.tensor([0.03, -0.02, 0.1]),
                     torch.zeros((), dtype=F64))
    depth = torch.full((2,), 3.5, dtype=F64)

    def energy(betas: torch.Tensor, transl: torch.Tensor) -> torch.Tensor:
        moved = FitState(betas, state.global_orient, state.body_pose, transl, state.log_scale)
        return term.per_frame(moved, track, depth, 1.0).sum()

    betas, transl = state.betas.clone().requires_grad_(True), state.transl.clone().requires_grad_(True)
    energy(betas, transl).backward()
    assert float(energy(betas, transl).detach()) > 0
    step = 1e-6
    with torch.no_grad():
        for k in range(len(betas)):
            nudge = step * torch.eye(len(betas), dtype=F64)[k]
            numeric = (energy(betas + nudge, transl) - energy(betas - nudge, transl)) / (2 * step)
            torch.testing.assert_close(betas.grad[k], numeric, rtol=1e-4, atol=1e-4)
        for index in np.ndindex(*transl.shape):
            nudge = torch.zeros_like(transl)
            nudge[index] = step
            numeric = (energy(betas, transl + nudge) - energy(betas, transl - nudge)) / (2 * step)
            torch.testing.assert_close(transl.grad[index], numeric, rtol=1e-4, atol=1e-4)


def test_legs_whose_keypoints_were_lost_are_placed_by_the_mask(model, config):
    """A walker whose knee and ankle keypoints the detector lost in every frame: the keypoints leave the legs to the
    pose prior (fitted without the walk, as to a motion it has not seen); the person's masks (drawn by the mesh
    z-buffer, not by the term's points) show them, and the fit that measures its outline against them places the
    knees and ankles nearer the true ones (relative to the pelvis)."""
    body = KeypointBody(model, keypoint_map("coco17", model.data))
    motion = builtin_motion("walk", 6, fps=10.0)
    truth = BodyParams(np.arange(6), np.zeros(10), np.tile([0.0, np.radians(20.0), 0.0], (6, 1)), motion.body_pose,
                       motion.transl + [0.0, 0.0, 3.5], 1.0, "free", np.zeros(6, bool))
    track, masks = _seen(model, body, truth)
    lost = [body.names.index(f"{side}_{joint}") for side in ("left", "right") for joint in ("knee", "ankle")]
    weight = track.weight.clone()
    weight[:, lost] = 0.0
    track = Track(track.frame_ids, track.times_s, track.points, weight, track.K, track.R, track.t)
    prior = build_pose_prior([m for m in config.pose_prior_motions if m != "walk"], config.pose_prior_floor_deg)
    schedule = FitSchedule(config.global_iterations, 40, tuple(config.pose_prior_anneal),
                           tuple(config.robust_scale_anneal), False, config.scale_motion_rate_hz)
    true_joints = body_joints(model, truth.betas, truth.global_orient, truth.body_pose, truth.transl)
    legs = [JOINT_NAMES.index(f"{side}_{joint}") for side in ("left", "right") for joint in ("knee", "ankle")]
    leg_error = {}
    for with_masks in (False, True):
        energy = FitEnergy(body, track, prior, joint_limits(), config.weights, config.max_interpolated_gap)
        if with_masks:
            energy.silhouette = _term(model, body, config, track, masks, config.silhouette.surface_points)
        outcome = fit_track(energy, initial_state_2d(body, track, prior.mean), schedule, "person test")
        s = outcome.state
        fitted = body_joints(model, s.betas.numpy(), s.global_orient.numpy(), s.body_pose.numpy(), s.transl.numpy())
        relative = (fitted - fitted[:, :1]) - (true_joints - true_joints[:, :1])
        leg_error[with_masks] = float(np.linalg.norm(relative[:, legs], axis=-1).mean())
        assert ("silhouette" in outcome.stages[-1]["energy"]) == with_masks
    assert leg_error[True] < 0.9 * leg_error[False], leg_error
