"""Stage 02's logic: one mode per person, ``provided`` > ``keypoints3d`` > ``keypoints2d`` unless
forced; body parameters for the frames the pipeline has (stage 01's cameras); the residuals
against whatever keypoints the scene gives.

Frames: a fitting mode fits the frames with a camera where the person has at least
``min_keypoints`` confident keypoints. Unobserved frames between two observed ones at most
``max_interpolated_gap`` apart get interpolated parameters (``interpolated`` marks them); other
unobserved frames get none (the person is absent there).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from glimpse.body.keypoints import keypoint_map
from glimpse.body.model import BODY_POSE_DIM
from glimpse.body.models import BodyModels
from glimpse.body.motion import interpolate_pose_sequence
from glimpse.body.params import BodyParams, read_body_shape, read_scene_smpl
from glimpse.cameras.align import rotation_between
from glimpse.cameras.model import PinholeCamera
from glimpse.cameras.undistort import scene_undistorter
from glimpse.errors import GlimpseError
from glimpse.fit.config import FitConfig, stated_person_heights, stated_person_shapes
from glimpse.fit.floor_fit import PendingFit, place_on_common_floor
from glimpse.fit.keypoint_body import KeypointBody
from glimpse.fit.keypoint_fit import (FitOutcome, FitSchedule, fit_track, initial_state_2d, initial_state_3d,
                                     mean_shape_keypoints)
from glimpse.fit.objective import FitEnergy, FitState, SilhouetteTerm, Track, motion_stride
from glimpse.fit.priors import (PartedPosePrior, PosePrior, build_parted_pose_prior, build_pose_prior, joint_limits,
                                representative_poses)
from glimpse.fit.residuals import body_keypoints, residuals_2d, residuals_3d, summary
from glimpse.fit.sampling import farthest_point_samples
from glimpse.fit.silhouette import SurfaceBody, linked_keypoints, silhouette_evidence
from glimpse.io.images import frame_name, read_mask
from glimpse.scene import HumanInputs, Scene, read_keypoints2d, read_keypoints3d

FIT_REPORT_FORMAT = "glimpse-fit-report/2"  # /2: residual keys carry their unit (_m, _px); fit stages added
GROUND_FORMAT = "glimpse-ground/1"  # ground.json: the floor step's report (glimpse.fit.floor_fit)
KEYPOINT_FILES = {"provided": "smpl.npz", "keypoints3d": "keypoints3d.npz", "keypoints2d": "keypoints2d.npz"}


@dataclass
class PersonFit:
    pid: str
    mode: str
    params: BodyParams
    report: dict


class Fitter:
    """What every person's fit shares: the body models (one per person, usually the same), their keypoint
    bodies, the priors, the cameras."""

    def __init__(self, scene: Scene, models: BodyModels, cameras: dict[int, PinholeCamera], config: FitConfig,
                 units: str):
        self.scene, self.models, self.cameras, self.config = scene, models, cameras, config
        self.dtype = models.default.dtype
        self.fit_scale = config.fit_scale == "always" or (config.fit_scale == "auto" and units == "sfm")
        self.undistorter = scene_undistorter(scene)
        self._bodies: dict[tuple[str, int], KeypointBody] = {}
        self._surfaces: dict[int, SurfaceBody] = {}
        self._prior: PosePrior | PartedPosePrior | None = None
        self._pose_hypotheses: torch.Tensor | None = None
        self._shapes: dict[str, np.ndarray] | None = None
        self._shape_files: dict[str, Path] = {}

    def observed(self, person: HumanInputs, mode: str) -> tuple[np.ndarray, str, np.ndarray]:
        """(frame_ids [T], layout, values [T, K, D+1]) of a person's 3D keypoints (world) or 2D keypoints
        (pixels of the undistorted frames stage 01 writes), the last channel being confidence."""
        if mode == "keypoints3d":
            kp3 = read_keypoints3d(person.keypoints3d)
            return kp3.frame_ids, kp3.layout, kp3.joints
        kp2 = read_keypoints2d(person.keypoints2d)
        values = kp2.keypoints.copy()
        seen = values[..., 2] > 0
        values[seen, :2] = self.undistorter.points(values[seen, :2])
        return kp2.frame_ids, kp2.layout, values

    def keypoint_body(self, layout: str, pid: str) -> KeypointBody:
        """Person ``pid``'s body model with the keypoints of ``layout`` (one per model and layout)."""
        model = self.models[pid]
        key = (layout, id(model))
        if key not in self._bodies:
            self._bodies[key] = KeypointBody(model, keypoint_map(layout, model.data))
        return self._bodies[key]

    @property
    def prior(self) -> PosePrior | PartedPosePrior:
        if self._prior is None:
            c = self.config
            if c.pose_prior_mixture and c.pose_prior_mixture_joints:
                self._prior = build_parted_pose_prior(c.pose_prior_motions, c.pose_prior_floor_deg,
                                                      tuple(c.pose_prior_mixture_joints), self.dtype)
            else:
                self._prior = build_pose_prior(c.pose_prior_motions, c.pose_prior_floor_deg, self.dtype,
                                               c.pose_prior_mixture)
        return self._prior

    @property
    def pose_hypotheses(self) -> torch.Tensor:
        """[H, 69] where 2D fits start their pose hypotheses: the pose prior's mean (where every fit starts)
        and H - 1 poses spread over the prior's motions (glimpse.fit.priors.representative_poses)."""
        if self._pose_hypotheses is None:
            c = self.config
            spread = representative_poses(c.pose_prior_motions, c.pose_hypotheses)[1:]
            self._pose_hypotheses = torch.cat([self.prior.mean[None], torch.as_tensor(spread, dtype=self.dtype)])
        return self._pose_hypotheses

    def image_keypoints(self, person: HumanInputs) -> tuple[np.ndarray, np.ndarray] | None:
        """(frame_ids [T], [T, K, 3] pixel x, y, confidence) of a person's confident keypoints in the
        undistorted frames: the 2D keypoints, else the 3D ones projected; None without either."""
        if person.keypoints2d is not None:
            frame_ids, _, values = self.observed(person, "keypoints2d")
        elif person.keypoints3d is not None:
            frame_ids, _, joints = self.observed(person, "keypoints3d")
            values = np.zeros((*joints.shape[:2], 3))
            for row, fid in enumerate(frame_ids):
                if int(fid) in self.cameras:
                    pixels, depth = self.cameras[int(fid)].project(joints[row, :, :3])
                    values[row, :, :2] = np.where(depth[:, None] > 0, pixels, 0.0)
                    values[row, :, 2] = np.where(depth > 0, joints[row, :, 3], 0.0)
        else:
            return None
        values[..., 2] = np.where(values[..., 2] >= self.config.keypoint_min_confidence, values[..., 2], 0.0)
        return frame_ids, values

    # ------------------------------------------------------------------------------------------ per person

    def fit_person(self, person: HumanInputs) -> PersonFit:
        """Body parameters of one person alone (no common floor), with a residual report."""
        return self.finish(self.start(person))

    def fit_people(self, people: list[HumanInputs],
                   progress: Callable[[list], Iterable] = iter) -> tuple[list[PersonFit], dict]:
        """Every person fitted, then those fitted from 2D keypoints placed on one floor (glimpse.fit.floor_fit)
        when 02_smpl_fit.ground allows; ``progress`` wraps the per-person loop (tqdm). Returns the fits and
        the floor's report."""
        heights, fitted = stated_person_heights(self.config.ground), [person.pid for person in people]
        for key, stated in (("ground.person_heights_m", heights), ("person_shapes", self.stated_shapes)):
            unknown = sorted(set(stated) - set(fitted))
            if unknown:  # before the fits, which take minutes
                raise GlimpseError(f"02_smpl_fit.{key} names {', '.join(unknown)}, not among the people fitted "
                                   f"({', '.join(fitted)})")
        both = sorted(set(heights) & set(self.stated_shapes))
        if both:
            raise GlimpseError(f"02_smpl_fit: {', '.join(both)} given both a height (ground.person_heights_m) and a "
                               f"shape (person_shapes); a shape tells the height too: give one")
        pending = [self.start(person) for person in progress(people)]
        floor = place_on_common_floor(pending, self.models, self.cameras, self.config, self.scene.fps)
        return [self.finish(p) for p in pending], floor

    @property
    def stated_shapes(self) -> dict[str, np.ndarray]:
        """pid -> betas [num_betas] of the people of 02_smpl_fit.person_shapes, read once."""
        if self._shapes is None:
            self._shape_files = stated_person_shapes(self.config)
            self._shapes = {pid: read_body_shape(path, self.models[pid].num_betas, self.scene.body_model)
                            for pid, path in self._shape_files.items()}
        return self._shapes

    def start(self, person: HumanInputs) -> PendingFit:
        """A person's own fit: given bodies read, keypoint fits run (global and full stages)."""
        mode = choose_mode(person, self.config)
        started = time.perf_counter()
        shape = self.stated_shapes.get(person.pid)
        if mode == "provided":
            if shape is not None:
                raise GlimpseError(f"person {person.pid}: 02_smpl_fit.person_shapes states a shape, but the body is "
                                   f"given (smpl.npz, mode provided), shape and all: drop the entry")
            params = read_scene_smpl(person.smpl, self.scene.body_model).select(sorted(self.cameras))
            if len(params.frame_ids) == 0:
                raise GlimpseError(f"person {person.pid}: smpl.npz has no frame among the {len(self.cameras)} "
                                   f"frames with a camera")
            return PendingFit(person, mode, seconds=time.perf_counter() - started, params=params)
        who, file = f"person {person.pid}", f"humans/{person.pid}/{KEYPOINT_FILES[mode]}"
        track, layout = self._track(person, mode)
        body = self.keypoint_body(layout, person.pid)
        energy = FitEnergy(body, track, self.prior, joint_limits(self.dtype), self.config.weights,
                           self.config.max_interpolated_gap)
        if track.is_2d and self.config.silhouette.mode == "auto" and person.masks:
            energy.silhouette = self.silhouette_term(person, track, body)
        c = self.config
        if len(c.robust_scale_anneal) != len(c.pose_prior_anneal):
            raise GlimpseError(f"02_smpl_fit.robust_scale_anneal {c.robust_scale_anneal} and pose_prior_anneal "
                               f"{c.pose_prior_anneal} must have one value per full-stage step each")
        for rate in ("scale_motion_rate_hz", "pose_hypothesis_rate_hz"):
            if not getattr(c, rate) > 0:
                raise GlimpseError(f"02_smpl_fit.{rate} must be above 0 (Hz), found {getattr(c, rate)}")
        if not c.weights.size_sigma >= 0:
            raise GlimpseError(f"02_smpl_fit.weights.size_sigma must be 0 (off) or more (relative), found "
                               f"{c.weights.size_sigma}")
        if c.pose_hypotheses < 1:
            raise GlimpseError(f"02_smpl_fit.pose_hypotheses must be at least 1 (1: only the prior's mean), "
                               f"found {c.pose_hypotheses}")
        schedule = FitSchedule(c.global_iterations, c.full_iterations, tuple(c.pose_prior_anneal),
                               tuple(c.robust_scale_anneal), self.fit_scale, c.scale_motion_rate_hz,
                               c.pose_hypothesis_iterations, c.pose_hypothesis_joint_speed_m_s,
                               c.pose_hypothesis_rate_hz, c.unseen_limbs_at_rest, shape is not None)
        try:
            if not track.is_2d:
                initial = initial_state_3d(body, track, self.prior.mean, self.fit_scale)
            elif person.keypoints3d is not None:
                initial = self._initial_from_3d(person, track, body)
            else:
                initial = initial_state_2d(body, track, self.prior.mean)
            if shape is not None:
                initial.betas = torch.as_tensor(shape, dtype=self.dtype)
            outcome = fit_track(energy, initial, schedule, who, self.pose_hypotheses if track.is_2d else None)
        except GlimpseError as exc:
            message = str(exc) if str(exc).startswith(who) else f"{who}: {exc}"
            raise GlimpseError(f"{message} ({file})") from None
        return PendingFit(person, mode, layout=layout, energy=energy, schedule=schedule, outcome=outcome,
                          seconds=time.perf_counter() - started)

    def finish(self, pending: PendingFit) -> PersonFit:
        """The person's body parameters (gaps filled) and report, after any floor refit."""
        person, mode = pending.person, pending.mode
        if pending.params is not None:
            params, fit_info = pending.params, {}
        else:
            params, fit_info = self._keypoint_result(pending)
        report = self.residual_report(person, params, mode)
        report.update(fit_info)
        if pending.ground:
            report["ground"] = pending.ground
        report["seconds"] = round(pending.seconds, 3)
        return PersonFit(person.pid, mode, params, report)

    def residual_report(self, person: HumanInputs, params: BodyParams, mode: str) -> dict:
        """Per-frame mean keypoint residuals of ``params`` against the scene's 3D (world units) and 2D
        (pixels) keypoints; interpolated frames are listed too (they were not fitted to those keypoints)."""
        report: dict = {"format": FIT_REPORT_FORMAT, "person": person.pid, "mode": mode,
                        "frames": len(params.frame_ids), "units_3d": "world units (metres in a metric frame)"}
        per_frame: dict[int, dict] = {int(f): {"interpolated": bool(i)}
                                      for f, i in zip(params.frame_ids, params.interpolated)}
        min_confidence = self.config.keypoint_min_confidence
        for key, path, unit in (("keypoints3d", person.keypoints3d, "m"), ("keypoints2d", person.keypoints2d, "px")):
            if path is None:
                continue
            frame_ids, layout, values = self.observed(person, key)
            predicted = dict(zip(params.frame_ids.tolist(), body_keypoints(self.models[person.pid], params,
                                                                            layout)))
            if key == "keypoints3d":
                residuals = residuals_3d(predicted, frame_ids, values, min_confidence)
            else:
                residuals = residuals_2d(predicted, frame_ids, values, self.cameras, min_confidence)
            report[f"{key}_residual_{unit}"] = summary(residuals)
            for fid, value in residuals.items():
                per_frame[fid][f"{key}_{unit}"] = value
        report["per_frame"] = {frame_name(f): v for f, v in sorted(per_frame.items())}
        return report

    def _keypoint_result(self, pending: PendingFit) -> tuple[BodyParams, dict]:
        outcome = pending.outcome
        params = self._with_gaps_filled(outcome, pending.energy.track.frame_ids.numpy())
        scale = params.scale
        info = {"layout": pending.layout, "fitted_frames": len(outcome.state.transl),
                "interpolated_frames": [frame_name(int(f)) for f in params.frame_ids[params.interpolated]],
                "absent_frames": [frame_name(f) for f in sorted(self.cameras) if f not in set(params.frame_ids)],
                "scale_fitted": self.fit_scale, "scale": scale, "metres_per_unit": 1.0 / scale,
                "pose_prior": self.prior.description, "stages": outcome.stages}
        if pending.person.pid in self.stated_shapes:
            info["shape_stated_from"] = str(self._shape_files[pending.person.pid])
        return params, info

    def surface_body(self, pid: str) -> SurfaceBody:
        """Person ``pid``'s body model's surface points of the silhouette term (one per model)."""
        model = self.models[pid]
        if id(model) not in self._surfaces:
            rest = model.v_template.double().numpy()
            self._surfaces[id(model)] = SurfaceBody(model, farthest_point_samples(
                rest, self.config.silhouette.surface_points))
        return self._surfaces[id(model)]

    def silhouette_term(self, person: HumanInputs, track: Track, body: KeypointBody) -> SilhouetteTerm | None:
        """The silhouette term of a 2D track from the person's masks (and the others', who may hide them) on
        frames about ``silhouette.rate_hz`` apart; None when none of those frames has a mask."""
        c = self.config.silhouette
        frame_ids = track.frame_ids.numpy()
        stride = motion_stride(track.times_s, c.rate_hz)
        rows = np.array([i for i in range(0, len(frame_ids), stride) if int(frame_ids[i]) in person.masks])
        if not len(rows):
            return None
        own, others = [], []
        for fid in frame_ids[rows].tolist():
            own.append(self.undistorter.mask(read_mask(person.masks[fid])))
            union = np.zeros_like(own[-1])
            for other in self.scene.humans.values():
                if other.pid != person.pid and fid in other.masks:
                    union |= self.undistorter.mask(read_mask(other.masks[fid]))
            others.append(union)
        evidence = silhouette_evidence(rows, own, others, stride, c.max_side_px, c.outline_pixels, self.dtype)
        surface = self.surface_body(person.pid)
        rest_keypoints, _ = mean_shape_keypoints(body, torch.zeros(BODY_POSE_DIM, dtype=self.dtype))
        links = linked_keypoints(surface.template.numpy(), rest_keypoints, c.linked_keypoints)
        return SilhouetteTerm(surface, evidence, torch.as_tensor(links), c.weight, c.noise_m, c.robust_m,
                              0.5 * surface.spacing_m() + c.clothing_m)

    def _track(self, person: HumanInputs, mode: str) -> tuple[Track, str]:
        """The person's confident keypoints on the frames with a camera and enough of them."""
        c, dtype = self.config, self.dtype
        all_ids, layout, values = self.observed(person, mode)
        confidence = np.where(values[..., -1] >= c.keypoint_min_confidence, values[..., -1], 0.0)
        keep = np.isin(all_ids, list(self.cameras)) & ((confidence > 0).sum(1) >= c.min_keypoints)
        if not keep.any():
            raise GlimpseError(
                f"person {person.pid}: humans/{person.pid}/{KEYPOINT_FILES[mode]} has no frame with at least "
                f"{c.min_keypoints} keypoints of confidence >= {c.keypoint_min_confidence} among the "
                f"{len(self.cameras)} frames with a camera; lower 02_smpl_fit.min_keypoints or "
                f"keypoint_min_confidence, or give humans/{person.pid}/smpl.npz")
        frame_ids = all_ids[keep]
        order = np.argsort(frame_ids)
        frame_ids, points, weight = frame_ids[order], values[keep][order, :, :-1], confidence[keep][order]
        extra = {}
        if mode == "keypoints2d":
            extra = {name: torch.as_tensor(np.stack([getattr(self.cameras[int(f)], name) for f in frame_ids]),
                                           dtype=dtype) for name in ("K", "R", "t")}
            relative3d = read_keypoints2d(person.keypoints2d).relative3d if c.relative3d else None
            if relative3d is not None:
                relative3d = relative3d[keep][order]
                rays = onto_viewing_rays(relative3d[..., :3], points, weight, extra["K"].numpy())
                extra["relative3d"] = torch.as_tensor(rays, dtype=dtype)
                extra["relative3d_weight"] = torch.as_tensor(
                    np.where(relative3d[..., 3] >= c.keypoint_min_confidence, relative3d[..., 3], 0.0), dtype=dtype)
        track = Track(torch.as_tensor(frame_ids), torch.as_tensor(frame_ids / self.scene.fps, dtype=dtype),
                      torch.as_tensor(points, dtype=dtype), torch.as_tensor(weight, dtype=dtype), **extra)
        return track, layout

    def _initial_from_3d(self, person: HumanInputs, track: Track, body: KeypointBody) -> FitState:
        """A 2D fit starting from the 3D keypoints' placement (frames without them copy the nearest)."""
        track3d, layout = self._track(person, "keypoints3d")
        common = np.isin(track3d.frame_ids.numpy(), track.frame_ids.numpy())
        if not common.any():
            return initial_state_2d(body, track, self.prior.mean)
        rows = np.searchsorted(track3d.frame_ids.numpy()[common], track.frame_ids.numpy()).clip(0, common.sum() - 1)
        subset = Track(track.frame_ids, track.times_s, track3d.points[common][rows], track3d.weight[common][rows])
        return initial_state_3d(self.keypoint_body(layout, person.pid), subset, self.prior.mean, self.fit_scale)

    def _with_gaps_filled(self, outcome: FitOutcome, fitted_ids: np.ndarray) -> BodyParams:
        state = outcome.state
        go, bp, tr = (x.numpy() for x in (state.global_orient, state.body_pose, state.transl))
        camera_ids = np.array(sorted(self.cameras))
        position = np.searchsorted(fitted_ids, camera_ids)
        inside = (position > 0) & (position < len(fitted_ids))
        before, after = fitted_ids[np.clip(position - 1, 0, None)], fitted_ids[np.clip(position, None, len(fitted_ids) - 1)]
        gap_ok = inside & (after - before <= self.config.max_interpolated_gap)
        wanted = np.isin(camera_ids, fitted_ids) | gap_ok
        out_ids = camera_ids[wanted]
        filled = interpolate_pose_sequence(fitted_ids.astype(float), go, bp, tr, out_ids.astype(float))
        interpolated = ~np.isin(out_ids, fitted_ids)
        return BodyParams(out_ids.astype(np.int64), state.betas.numpy().copy(), filled["global_orient"],
                          filled["body_pose"], filled["transl"], float(math.exp(float(state.log_scale))),
                          self.scene.body_model, interpolated)


def onto_viewing_rays(relative: np.ndarray, pixels: np.ndarray, weight: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Metric 3D keypoints in the image's axes as a camera looking straight at the person sees them
    (relative [T, J, 3], SCENE_FORMAT.md) -> the same points in the camera's axes: each frame's points turned
    by the smallest rotation that takes the optical axis onto the ray through the person's confident pixel
    keypoints' centre (pixels [T, J, 2], weight [T, J], intrinsics K [T, 3, 3]). A frame with no confident
    keypoint is left as it is."""
    out = relative.copy()
    for t in range(len(relative)):
        seen = weight[t] > 0
        if not seen.any():
            continue
        ray = np.linalg.solve(K[t], np.append(pixels[t, seen].mean(0), 1.0))
        out[t] = relative[t] @ rotation_between(np.array([0.0, 0.0, 1.0]), ray).T
    return out


def choose_mode(person: HumanInputs, config: FitConfig) -> str:
    available = [m for m, path in (("provided", person.smpl), ("keypoints3d", person.keypoints3d),
                                   ("keypoints2d", person.keypoints2d)) if path is not None]
    if config.mode != "auto":
        if config.mode not in available:
            raise GlimpseError(f"person {person.pid}: 02_smpl_fit.mode={config.mode} needs "
                               f"humans/{person.pid}/{KEYPOINT_FILES[config.mode]}; the scene has: "
                               f"{', '.join(available) or 'none'}")
        return config.mode
    if not available:
        raise GlimpseError(f"person {person.pid}: no smpl.npz, keypoints3d.npz or keypoints2d.npz to fit a body to "
                           f"(masks alone do not give a body)")
    return available[0]


