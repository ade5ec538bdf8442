"""Stage 02's floor step: every person's own fit done, the people fitted from 2D keypoints are put
on one floor (glimpse.fit.ground) and refitted with their feet on it.

1. Each person's sole points (heels, big toes) over its fitted frames; contacts are the sole
   points that stay put across the view and are the body's lowest.
2. The floor's normal from all contacts (each person's centred on its own), where the contacts do not
   tell the up from the people's 2D torso axes (their vertical vanishing point) and their bodies' mean up;
   each person's own contact plane along it.
3. Each 2D-fitted person is moved along the camera's rays and scaled (betas) by the factor that
   puts its contact plane on the common floor (people whose size the keypoints do not tell: their common
   size from a stature prior, each keeping the size the floor gives it), then refitted with the floor term on
   (glimpse.fit.objective.FloorContact: contacts on the floor, nothing below it, no sliding).

Steps 2 and 3 only in a metric frame: a person moved in each frame along that frame's rays, about
that frame's camera centre, and scaled with it, still projects to the same pixels in every frame. A
moving camera's heights are measured from its mean centre: exact while the camera keeps its height,
off by the camera's rise times (1 - factor) where it does not. A moving camera with only one
person (whose own feet alone tilt a floor: docs/fitting.md), or in SfM units, gets planted feet
only: a sole point that touches the ground does not slide, which, seen from the camera's path,
pins where the person stands.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from glimpse.body.keypoints import landmark_map
from glimpse.body.models import BodyModels
from glimpse.body.params import BodyParams
from glimpse.cameras.model import PinholeCamera
from glimpse.errors import GlimpseError
from glimpse.fit.config import FitConfig, GroundConfig, stated_person_heights
from glimpse.fit.ground import (SOLE_LANDMARKS, Floor, floor_normal, foot_contacts, implausible_factors,
                                lowest_points, near_own_plane, parallax_factor, person_camera_heights,
                                placement_factors, plane_weights, speed_across_view, standing_weights,
                                stature_scale, torso_axis_planes, torso_axis_sigmas,
                                vertical_from_torsos)
from glimpse.fit.keypoint_body import KeypointBody
from glimpse.fit.keypoint_fit import FitOutcome, FitSchedule, refit_on_floor, rescale_about
from glimpse.fit.objective import TEMPLATE_SIZE, FitEnergy, FloorContact
from glimpse.scene import HumanInputs

HIPS, KNEES = [1, 2], [4, 5]  # SMPL joint indices (left, right)
ANCHOR_MODES = ("provided", "keypoints3d")  # people placed metrically: they fix the camera's height (so do people
# fitted from 2D keypoints with a stated shape: knowing their size, their own fit knows their distance)
STATIC_CAMERA_TOLERANCE = 1e-6  # world units (relative to the centre's norm + 1): a static camera's centres agree
TORSO_KEYPOINTS = ("left_hip", "right_hip", "left_shoulder", "right_shoulder")  # a 2D torso axis: hips to shoulders
TORSO_ITERATIONS = 20  # reweighting rounds of the torso axes' robust fit (converged well before)
PARALLAX_RUN_GAP_FRAMES = 1  # a planted foot's run is consecutive scene frames: a missing one may hide a step
STATURE_SEARCH_LOG, STATURE_SEARCH_STEP = 0.7, 0.001  # the common size is searched within exp(+-0.7), 0.1% steps


@dataclass
class PendingFit:
    """A person between its own fit and the common floor: given bodies (``params``), or a keypoint fit's
    energy (track, priors), schedule and outcome, which the floor step may refit. ``ground`` collects
    what the floor step did; ``seconds`` is the fitting time so far."""

    person: HumanInputs
    mode: str
    seconds: float = 0.0
    params: BodyParams | None = None
    layout: str = ""
    energy: FitEnergy | None = None
    schedule: FitSchedule | None = None
    outcome: FitOutcome | None = None
    ground: dict = field(default_factory=dict)


@dataclass
class _Feet:
    soles: np.ndarray  # [T, S, 3] world
    up: np.ndarray  # [T, 3] the body's up in the world
    frame_ids: np.ndarray  # [T] the person's fitted frames
    centres: np.ndarray  # [T, 3] the camera's centre in each of the person's frames (world)
    standing: np.ndarray  # [T] how upright the frame's body stands (1: thighs along -up), weights the up hint
    contact: np.ndarray  # [T, S] bool


def place_on_common_floor(pending: list[PendingFit], models: BodyModels, cameras: dict[int, PinholeCamera],
                          config: FitConfig, fps: float) -> dict:
    """Put the 2D-fitted people of ``pending`` on one floor and refit them (updating their outcomes);
    ``models`` gives each person's body model, ``fps`` is the scene's frame rate. Returns the floor report
    (``applied`` false with the reason when the step does not apply; ``stated_not_used`` names the people of
    ``ground.person_heights_m`` whose height had nothing to act through)."""
    report = _place(pending, models, cameras, config, fps)
    g = config.ground
    scaled = {p.person.pid for p in pending if "stated_height_m" in p.ground}
    unused = [pid for pid in stated_person_heights(g) if pid not in scaled]
    if unused:
        report["stated_not_used"] = (f"02_smpl_fit.ground.person_heights_m ({', '.join(unused)}): a stated height "
                                     f"sets the size of a person fitted from 2D keypoints in a metric frame, on the "
                                     f"common floor unless people placed metrically set it (or, with planted feet "
                                     f"only, on the person alone); here it did not (no floor, no ground points, "
                                     f"another mode, or SfM units: see reason, why and camera_height_from)")
    return report


def _place(pending: list[PendingFit], models: BodyModels, cameras: dict[int, PinholeCamera], config: FitConfig,
           fps: float) -> dict:
    """place_on_common_floor's work."""
    g = config.ground
    frame_centres = {f: cameras[f].centre for f in sorted(cameras)}
    centres = np.stack(list(frame_centres.values()))
    static = _static(centres)
    reason = _why_not(pending, static, g)
    if reason is not None:
        return {"applied": False, "reason": reason}
    soles: dict[int, KeypointBody] = {}  # per distinct body model
    for p in pending:
        model = models[p.person.pid]
        if id(model) not in soles:
            soles[id(model)] = KeypointBody(model, landmark_map("soles", SOLE_LANDMARKS, model.data))
    soles_bodies = [soles[id(models[p.person.pid])] for p in pending]
    feet = [_feet(p, body, frame_centres, config, fps) for p, body in zip(pending, soles_bodies)]
    if not static:
        planted_why = _why_planted_feet_only(pending, g)
        if planted_why is not None:
            return _plant_feet(pending, feet, soles_bodies, g, planted_why, _stated_factors(pending, models, g),
                               models)
    centre = centres[0] if static else centres.mean(0)  # a moving camera's heights are measured from its mean
    up_hint = sum((f.standing[:, None] * f.up).sum(0) for f in feet)
    if np.linalg.norm(up_hint) <= 0:
        return {"applied": False, "reason": "nobody stands upright in any frame (no up to start the floor from)"}
    up_hint = up_hint / np.linalg.norm(up_hint)
    bodies_up = up_hint
    if g.up_from == "torso_axes":
        up_hint = _torso_vertical(pending, feet, up_hint, g)
    grounded = [lowest_points(f.soles, up_hint) for f in feet]
    normal_prior_m = g.normal_prior(static)
    normal = floor_normal(grounded, up_hint, normal_prior_m)
    grounded = near_own_plane(grounded, normal, centre, g.contact_height_m)
    normal = floor_normal(grounded, up_hint, normal_prior_m)
    heights = person_camera_heights(grounded, normal, centre)
    anchored = np.array([p.mode in ANCHOR_MODES or (p.schedule is not None and p.schedule.shape_stated)
                         for p in pending])
    if (heights <= 0).any():  # nan (no points) compares False
        below = [p.person.pid for p, h in zip(pending, heights) if h <= 0]
        return {"applied": False, "reason": f"the people's feet do not agree on a floor: the camera would stand "
                                            f"below the feet of {', '.join(below)} (a fit with its legs wrong?)"}
    trust = plane_weights(grounded, normal, centre, g.floor_sigma_m)
    parallax, measured, measured_weights = [], None, None  # (factor, relative error) per person, moving camera
    if not static:
        if g.parallax_max_error > 0 and not g.parallax_size_error > 0:  # the error only weighs factors in use
            raise GlimpseError(f"02_smpl_fit.ground.parallax_size_error must be above 0 (relative), found "
                               f"{g.parallax_size_error}")
        rank = {f: k for k, f in enumerate(sorted(cameras))}  # a frame's place among the scene's frames
        parallax = [_parallax(p, f, rank, config) for p, f in zip(pending, feet)]
        measured = np.array([factor * height for (factor, _), height in zip(parallax, heights)])
        measured_weights = np.array([1.0 / (error**2 + g.parallax_size_error**2) for _, error in parallax])
    stated = _stated_factors(pending, models, g)
    stated[~np.isfinite(heights) | anchored.any()] = np.nan  # no ground points, or people placed metrically decide
    if np.isfinite(stated).any():  # heights the user knows outweigh every cue measured here
        measured, measured_weights = stated * heights, np.ones(len(pending))
    camera_height, factors = placement_factors(heights, anchored, trust, measured, measured_weights)
    if not np.isfinite(camera_height):
        return {"applied": False, "reason": "no person's feet were seen on the ground"}
    floor_sizes = g.statures_on_floor and any(_size_unobserved(p) for p in pending)
    # nothing metric: no anchors, and no measured heights (the parallax of planted feet, or stated heights)
    by_statures = floor_sizes and not (anchored.any() or (measured is not None and bool(np.isfinite(measured).any())))
    if by_statures:
        common = _stature_prior_factor(pending, factors, models, g)
        camera_height, factors = camera_height * common, factors * common
    implausible = [f"{pending[i].person.pid} ({factors[i]:.2f})"
                   for i in implausible_factors(factors, g.max_placement_factor)]
    if implausible:
        return {"applied": False, "reason": f"the people's feet do not agree on a floor: it would move "
                                            f"{', '.join(implausible)} to that many times its distance and size, "
                                            f"beyond 02_smpl_fit.ground.max_placement_factor "
                                            f"({g.max_placement_factor})"}
    floor = Floor(normal, centre, camera_height)
    for k, (p, f, height, factor, soles_body) in enumerate(zip(pending, feet, heights, factors, soles_bodies)):
        p.ground = {"contact_sole_points": int(f.contact.sum()), "factor": float(factor),
                    "camera_height_above_own_ground": float(height) if np.isfinite(height) else None}
        if parallax:
            p.ground["parallax_factor"] = parallax[k][0] if np.isfinite(parallax[k][0]) else None
        if p.mode == "keypoints2d":  # moved by its factor even without contacts (its lowest points placed it)
            started = time.perf_counter()
            keep_size = (floor_sizes and _size_unobserved(p)) or bool(np.isfinite(stated[k]))
            p.ground["refit"] = _refit(p, f, soles_body, g, floor, float(factor), keep_size=keep_size)
            p.seconds += time.perf_counter() - started
        if np.isfinite(stated[k]):
            _report_stated_height(p, models, g, stated[k])
    return {"applied": True, "normal": normal.tolist(), "camera_centre": centre.tolist(),
            "camera_height": camera_height, "camera_moves": not static, "up_from": g.up_from,
            "up_from_bodies_deg": float(np.degrees(np.arccos(np.clip(bodies_up @ up_hint, -1.0, 1.0)))),
            "camera_height_from": _camera_height_from(pending, anchored, measured, stated, by_statures),
            "factors": {p.person.pid: float(s) for p, s in zip(pending, factors)}}


def _size_unobserved(pending: PendingFit) -> bool:
    """A person fitted from 2D keypoints that do not tell its size, held by the size prior in its own fit
    (weights.size_sigma above 0): on the common floor (``statures_on_floor``) it keeps the size the floor gives it."""
    return pending.mode == "keypoints2d" and pending.energy.holds_size


def _stature_prior_factor(pending: list[PendingFit], factors: np.ndarray, models: BodyModels,
                          g: GroundConfig) -> float:
    """The factor that scales every 2D-fitted person's stature on the floor (fitted stature times ``factors`` [P])
    to the most probable set under the stature prior (glimpse.fit.ground.stature_scale), adults about the body
    model's template stature (what the size prior pulls towards)."""
    statures = np.array([_fitted_height(p, models) * f if p.mode == "keypoints2d" else np.nan
                         for p, f in zip(pending, factors)])
    first = next(p for p in pending if p.mode == "keypoints2d")
    model = models[first.person.pid]
    with torch.no_grad():
        template = float(model.stature(torch.zeros(first.outcome.state.betas.shape[-1], dtype=model.dtype)))
    return stature_scale(statures, template, g.stature_adult_sigma, g.stature_child_m, g.stature_child_sigma,
                         g.stature_child_share, STATURE_SEARCH_LOG, STATURE_SEARCH_STEP)


def _torso_vertical(pending: list[PendingFit], feet: list[_Feet], up_hint: np.ndarray, g: GroundConfig) -> np.ndarray:
    """The world's up from where the 2D-fitted people's torso axes meet (glimpse.fit.ground.vertical_from_torsos),
    over their upright frames (``standing`` weights) whose hips and shoulders are all at least
    ``torso_min_confidence``; ``up_hint`` (the bodies' mean up) where they do not tell. The fitted bodies lean
    with the camera's pitch on a detector's keypoints (docs/fitting.md); a 2D axis does not."""
    planes, sigmas, weights = [], [], []
    for p, f in zip(pending, feet):
        if p.mode != "keypoints2d" or not set(TORSO_KEYPOINTS) <= set(p.energy.body.names):
            continue
        track, names = p.energy.track, list(p.energy.body.names)
        hips, shoulders = ([names.index(n) for n in pair] for pair in (TORSO_KEYPOINTS[:2], TORSO_KEYPOINTS[2:]))
        points, confidence = track.points.numpy(), track.weight.numpy()
        seen = confidence[:, hips + shoulders].min(1) >= g.torso_min_confidence
        planes.append(torso_axis_planes(points[:, hips], points[:, shoulders], track.K.numpy(), track.R.numpy()))
        sigmas.append(torso_axis_sigmas(points[:, hips], points[:, shoulders], np.radians(g.torso_axis_sigma_deg),
                                        g.torso_keypoint_noise_px))
        weights.append(f.standing * seen)
    if not planes:
        return up_hint
    return vertical_from_torsos(np.concatenate(planes), np.concatenate(weights), up_hint, np.concatenate(sigmas),
                                np.radians(g.torso_up_sigma_deg), TORSO_ITERATIONS)


def _parallax(pending: PendingFit, feet: _Feet, rank: dict[int, int], config: FitConfig) -> tuple[float, float]:
    """(factor, relative error) of a 2D-fitted person's planted feet under a moving camera
    (glimpse.fit.ground.parallax_factor); ``rank`` gives each frame id its place among the scene's frames (a
    video subsampled at ingest keeps its own frame numbers). (nan, inf) for other people, for an error above
    ``ground.parallax_max_error`` and when that is 0."""
    if pending.mode != "keypoints2d" or config.ground.parallax_max_error <= 0:
        return float("nan"), float("inf")
    frames = np.array([rank[int(f)] for f in feet.frame_ids])
    factor, error = parallax_factor(feet.soles, feet.contact, feet.centres, frames, PARALLAX_RUN_GAP_FRAMES)
    if not (np.isfinite(factor) and factor > 0 and error <= config.ground.parallax_max_error):
        return float("nan"), float("inf")
    return factor, error


def _stated_factors(pending: list[PendingFit], models: BodyModels, g: GroundConfig) -> np.ndarray:
    """[P] for each 2D-fitted person of ``ground.person_heights_m``, that height over its fitted standing height
    (the factor that makes it as tall as stated); nan for everyone else."""
    known = stated_person_heights(g)
    factors = np.full(len(pending), np.nan)
    for k, p in enumerate(pending):
        if p.person.pid in known and p.mode == "keypoints2d":
            factors[k] = known[p.person.pid] / _fitted_height(p, models)
    return factors


def _fitted_height(pending: PendingFit, models: BodyModels) -> float:
    """The person's standing height as its fit now stands (metres: the shape's stature times the fitted scale)."""
    state = pending.outcome.state
    with torch.no_grad():
        return float(models[pending.person.pid].stature(state.betas) * state.log_scale.exp())


def _report_stated_height(pending: PendingFit, models: BodyModels, g: GroundConfig, factor: float) -> None:
    """A stated person's ``ground`` report: the stated height, the height its own fit gave before it was scaled by
    ``factor``, and the height after the refit (the rescale fits its skeleton, not its stature: within a few cm)."""
    stated = stated_person_heights(g)[pending.person.pid]
    pending.ground.update({"stated_height_m": stated, "height_as_fitted_alone_m": stated / factor,
                           "height_m": _fitted_height(pending, models)})


def _camera_height_from(pending: list[PendingFit], anchored: np.ndarray, measured: np.ndarray | None,
                        stated: np.ndarray, by_statures: bool) -> str:
    """What set the camera's height above the common floor, in words (ground.json)."""
    anchors = [p.person.pid for p, a in zip(pending, anchored) if a]
    if anchors:
        return "people placed metrically (3D keypoints, given bodies, stated shapes): " + ", ".join(anchors)
    told = [p.person.pid for p, s in zip(pending, stated) if np.isfinite(s)]
    if told:
        return "the heights stated in 02_smpl_fit.ground.person_heights_m: " + ", ".join(told)
    cued = [p.person.pid for p, m in zip(pending, measured if measured is not None else []) if np.isfinite(m)]
    if cued:
        return ("the parallax of planted feet as the camera moves (each person's factor that makes them stand "
                "still), over: " + ", ".join(cued))
    if by_statures:
        return ("the people's statures as the floor gives them, scaled together to the most probable under the "
                "stature prior (02_smpl_fit.ground.stature_*); each person keeps the size the floor gives it")
    return ("the geometric mean over the people (their fitted heights on average), each weighted by how flat its "
            "own ground points lie")


def _why_not(pending: list[PendingFit], static: bool, g: GroundConfig) -> str | None:
    """Why the floor step does not apply (None when it does)."""
    movable = [p for p in pending if p.mode == "keypoints2d"]
    if g.mode == "off":
        return "02_smpl_fit.ground.mode is off"
    if not movable:
        return "no person is fitted from 2D keypoints"
    if static and any(p.schedule.fit_scale for p in movable):
        return "the frame is not metric (the scale is fitted)"
    return None


def _why_planted_feet_only(pending: list[PendingFit], g: GroundConfig) -> str | None:
    """Why a moving camera's people get planted feet only instead of the common floor (None: the floor)."""
    if g.moving_camera == "planted_feet":
        return "02_smpl_fit.ground.moving_camera is planted_feet"
    if len(pending) < 2:
        return "one person: a floor through a lone person's own fitted feet tilts with its depth errors"
    if any(p.schedule.fit_scale for p in pending if p.mode == "keypoints2d"):
        return "the frame is not metric (the scale is fitted)"
    return None


def _static(centres: np.ndarray) -> bool:
    """Whether the cameras' centres [N, 3] (world) agree: a static camera."""
    tolerance = STATIC_CAMERA_TOLERANCE * (1.0 + np.linalg.norm(centres[0]))
    return bool(np.allclose(centres, centres[0], rtol=0.0, atol=tolerance))


def _plant_feet(pending: list[PendingFit], feet: list[_Feet], soles_bodies: list[KeypointBody],
                g: GroundConfig, why: str, stated: np.ndarray, models: BodyModels) -> dict:
    """A moving camera without the common floor (``why``): each 2D-fitted person is refitted with its feet
    held still while they touch the ground, which, seen from the camera's path, pins where the person stands.
    A person of stated height in a metric frame is first moved along each frame's rays to that height (by
    its ``stated`` [P] factor, nan where none)."""
    for k, (p, f, soles_body) in enumerate(zip(pending, feet, soles_bodies)):
        p.ground = {"contact_sole_points": int(f.contact.sum())}
        if p.mode == "keypoints2d":
            factor = 1.0
            scaled = bool(np.isfinite(stated[k])) and not p.schedule.fit_scale
            if scaled:
                factor = float(stated[k])
                p.ground["factor"] = factor
            started = time.perf_counter()
            p.ground["refit"] = _refit(p, f, soles_body, g, factor=factor, keep_size=scaled)
            p.seconds += time.perf_counter() - started
            if factor != 1.0:
                _report_stated_height(p, models, g, factor)
    return {"applied": True, "planted_feet_only": True,
            "why": f"the camera moves and {why}: each person fitted from 2D keypoints is refitted with its feet still "
                   f"while they touch the ground (no common floor plane, no placement factors)"}


def _feet(pending: PendingFit, soles_body: KeypointBody, centres: dict[int, np.ndarray], config: FitConfig,
          fps: float) -> _Feet:
    """The person's sole points, up, standing weights and contacts; ``centres`` the camera centre per frame id."""
    dtype = soles_body.joint_template.dtype
    if pending.params is not None:
        params = pending.params.select(pending.params.frame_ids[~pending.params.interpolated])
        betas, orient, pose, transl = (torch.as_tensor(x, dtype=dtype) for x in
                                       (params.betas, params.global_orient, params.body_pose, params.transl))
        scale = float(params.scale)
        frame_ids = params.frame_ids
        times = frame_ids / fps
    else:
        state = pending.outcome.state
        betas, orient, pose, transl, scale = (state.betas, state.global_orient, state.body_pose, state.transl,
                                              float(state.log_scale.exp()))
        frame_ids = pending.energy.track.frame_ids.numpy()
        times = pending.energy.track.times_s.numpy()
    with torch.no_grad():
        out = soles_body(betas, orient, pose, transl, torch.tensor(scale, dtype=dtype))
    soles, joints = out.keypoints.numpy(), out.joints.numpy()
    up = Rotation.from_rotvec(orient.numpy()).apply([0.0, 1.0, 0.0])
    standing = standing_weights(up, joints[:, HIPS], joints[:, KNEES], config.ground.standing_thigh_deg)
    g = config.ground
    frame_centres = np.stack([centres[int(f)] for f in frame_ids])
    speed = speed_across_view(soles, times, frame_ids, frame_centres, config.max_interpolated_gap,
                              g.contact_span_s)
    return _Feet(soles, up, frame_ids, frame_centres, standing,
                 foot_contacts(soles, up, speed, scale, g.contact_speed_m_s, g.contact_height_m))


def _refit(pending: PendingFit, feet: _Feet, soles_body: KeypointBody, g: GroundConfig, floor: Floor | None = None,
           factor: float = 1.0, keep_size: bool = False) -> dict:
    """Refit ``pending`` moved by ``factor`` about each frame's camera centre onto ``floor``; without a floor,
    with planted feet only (moved only where a stated height gives a factor). Otherwise the size prior
    (02_smpl_fit.weights.size_sigma) still pulls towards the template's size, against the floor's factor: one
    more cue, weighed in the same energy; ``keep_size`` (a person of stated height, or one whose size the keypoints
    do not tell when ``statures_on_floor``) holds the moved size."""
    energy, outcome = pending.energy, pending.outcome
    dtype = outcome.state.transl.dtype
    state, plane = outcome.state, None
    if floor is not None or factor != 1.0:
        state = rescale_about(state, energy.body, torch.as_tensor(feet.centres, dtype=dtype), factor, g.shape_ridge,
                              keep_shape=pending.schedule.shape_stated)
    if floor is not None:
        plane = (torch.as_tensor(floor.normal, dtype=dtype), torch.as_tensor(floor.camera_centre, dtype=dtype),
                 floor.camera_height)
    energy.floor = FloorContact(soles_body, torch.as_tensor(feet.contact, dtype=dtype), g.floor_sigma_m,
                                g.skate_sigma_m_s, plane)
    if keep_size:  # a stated height: the size prior holds the size it gave, not the template's
        with torch.no_grad():
            energy.size_target = float(energy.body.size_ratio(state.betas))
    stage = refit_on_floor(energy, state, pending.schedule, g.iterations, f"person {pending.person.pid}")
    energy.floor, energy.size_target = None, TEMPLATE_SIZE
    outcome.state = state.detached()
    outcome.stages.append(stage)
    return stage
