"""The fitting energy of one person over T frames (SMPLify-style, in the spirit of a log posterior):

    E = data + w_pose * anneal * pose prior + w_limits * joint limits + w_shape * shape prior + size prior
        + smoothness + speed + speed limit

- data: sum over confident keypoints of ``c * (rho^2 / sigma^2) * r^2 / (r^2 + rho^2)``, a Geman-McClure
  robust square: ``c r^2 / sigma^2`` for residuals well below ``rho``, bounded above. ``r`` is the
  residual in metres at the person: the 3D distance, or the pixel distance times depth / focal length
  (so 2D and 3D fits share sigma, and a far person weighs as much as a near one). ``rho`` is wider for 3D
  keypoints: given ones rarely have outliers, and with a narrow one a deep crouch's ankles, far from where
  the prior holds them early on, pull too weakly for the fit to reach them in its iterations.
- metric 3D (2D tracks that carry it: keypoints2d.npz's ``relative3d``, a monocular 3D pose model's output):
  the same robust square on the distance between each keypoint relative to the mid hip, turned into the
  camera's axes and measured in metres of body, and the model's metric point, with its own noise and robust
  scales. It tells the pose's depth (which way a limb bends towards the camera) and, through the body's
  metric size, how far the person is; the pixel keypoints still say where.
- smoothness: squared joint accelerations (second differences over the frames' times, seconds) over
  ``sigma_acc^2``, between frames at most ``max_gap`` frames apart; speed (only when the scale is
  fitted): the pelvis's squared speed over ``sigma_v^2`` (people walk at about 1.4 m/s). Both in
  metres of body (world units divided by the person's scale), so in SfM units they tell the scale:
  placed at the wrong depth in every frame of a moving camera, a person would race along an arc.
  Speed limit (every fit): the pelvis's speed above ``speed_limit`` (a run), squared, over
  ``sigma_limit^2``, measured between frames about ``span`` seconds apart. One view tells a person's
  distance only by their size in the image, and a few frames with misleading keypoints (a person half
  hidden behind others, an ankle found on someone else) can put them metres away and back within a
  second; no walker does that. Below the limit it costs nothing, so it holds no walker back.
  Accelerations are also divided by the body's size over the template's (``KeypointBody.size_ratio``):
  in one view a smaller body nearer the camera projects to the same pixels and accelerates less, so
  in metres the term would pull every 2D fit small and near.
- silhouette (2D tracks of people with masks, glimpse.fit.silhouette): surface points of the body that project
  outside what may show the person, and pixels of the mask's outline no projected point reaches, each the same
  robust square in metres at the person, averaged over the points and over the outline, times ``weight`` (as if
  so many keypoints); on every few frames, each standing for the frames between. The mask shows what keypoints
  do not (the top of the head, the feet, a limb whose keypoints were lost), without the keypoints' noise.
- size prior (2D tracks without a metric size, ``size_sigma`` above 0): per fitted frame,
  ``(log(size / target) / size_sigma)^2``, size the body's over the template's (``KeypointBody.size_ratio``).
  One view cannot tell a body's size from its distance; only its proportions hint at it, and a detector's
  keypoints (its own idea of where a hip or a shoulder is) make the proportions say a body 9-13% too large,
  in every frame alike: a body fitted 10% too large stands 10% too far. The target is the template's size
  (1), also in the floor step, where the floor's placement factor pulls the other way and the energy weighs
  the two; a person of stated height is held to the size that height gave (``FitEnergy.size_target``).
- floor (only in stage 02's floor step, glimpse.fit.floor_fit): sole points of the contact frames
  on the people's common floor, ``(height / sigma_floor)^2``, and any sole point below it, the same
  (static camera only); contact points that slide between consecutive contact frames,
  ``(speed / sigma_skate)^2``. Heights and speeds in metres of body.
Every term is a sum over frames (not a mean), so the priors weigh less where keypoints are many.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch
from torch import Tensor

from glimpse.fit.config import FitWeights
from glimpse.fit.ground import height_above_plane
from glimpse.fit.keypoint_body import KeypointBody
from glimpse.fit.priors import JointLimits, PartedPosePrior, PosePrior, shape_energy, size_energy
from glimpse.fit.silhouette import SilhouetteEvidence, SurfaceBody, silhouette_residuals_px

HIP_NAMES = ("left_hip", "right_hip")  # relative3d is measured from their mid point
TEMPLATE_SIZE = 1.0  # KeypointBody.size_ratio of the template (betas 0): what the size prior pulls towards
SPEED_EPSILON = 1e-12  # (m/s)^2 added under a speed's square root: differentiable where the speed is 0
MIN_CAMERA_DEPTH = 1e-3  # world units; points nearer than this (or behind) project as if at this depth


@dataclass(frozen=True)
class Track:
    """One person's observations over T frames.
    points [T, K, 3] world units (3D) or [T, K, 2] pixels (2D); weight [T, K] confidence, 0 = unused;
    times_s [T] seconds; frame_ids [T] ints; for 2D, cameras K/R/t [T, 3, 3], [T, 3, 3], [T, 3], and
    optionally relative3d [T, K, 3] (metres from the mid hip, the camera's axes) with relative3d_weight [T, K]."""

    frame_ids: Tensor
    times_s: Tensor
    points: Tensor
    weight: Tensor
    K: Tensor | None = None
    R: Tensor | None = None
    t: Tensor | None = None
    relative3d: Tensor | None = None
    relative3d_weight: Tensor | None = None

    @property
    def is_2d(self) -> bool:
        return self.points.shape[-1] == 2

    def only(self, keypoints: list[int]) -> "Track":
        """The same track with every other keypoint's weight set to 0."""
        keep = torch.zeros(self.weight.shape[1], dtype=self.weight.dtype)
        keep[keypoints] = 1.0
        relative_weight = None if self.relative3d_weight is None else self.relative3d_weight * keep
        return replace(self, weight=self.weight * keep, relative3d_weight=relative_weight)

    def repeated(self, times: int) -> "Track":
        """The track's frames repeated ``times`` times along the frame axis (a batch of hypotheses)."""
        return Track(*(None if v is None else repeat_frames(v, times) for v in vars(self).values()))


def repeat_frames(values: Tensor, times: int) -> Tensor:
    """[T, ...] -> [times * T, ...]: the whole sequence repeated ``times`` times (a batch of hypotheses)."""
    return values.repeat(times, *([1] * (values.ndim - 1)))


@dataclass
class FitState:
    """The unknowns: betas [10] (shared), global_orient [T, 3], body_pose [T, 69], transl [T, 3],
    log_scale [] (world units per metre of body, log)."""

    betas: Tensor
    global_orient: Tensor
    body_pose: Tensor
    transl: Tensor
    log_scale: Tensor

    def detached(self) -> "FitState":
        return FitState(*(v.detach().clone() for v in vars(self).values()))


def project(points: Tensor, K: Tensor, R: Tensor, t: Tensor) -> tuple[Tensor, Tensor]:
    """points [T, N, 3] world -> (pixels [T, N, 2], depth [T, N]) through per-frame cameras."""
    cam = torch.einsum("tij,tnj->tni", R, points) + t[:, None]
    depth = cam[..., 2]
    z = depth.clamp(min=MIN_CAMERA_DEPTH)
    pixels = cam[..., :2] / z[..., None] * torch.stack([K[:, 0, 0], K[:, 1, 1]], -1)[:, None] + K[:, None, :2, 2]
    return pixels, depth


def keypoint_residual_m(keypoints: Tensor, track: Track, depth_ref: Tensor | None) -> Tensor:
    """[T, K] residuals in metres at the person (see the module docstring). depth_ref [T] for 2D."""
    if not track.is_2d:
        return (keypoints - track.points).norm(dim=-1)
    pixels, _ = project(keypoints, track.K, track.R, track.t)
    focal = 0.5 * (track.K[:, 0, 0] + track.K[:, 1, 1])
    return (pixels - track.points).norm(dim=-1) * (depth_ref / focal)[:, None]


def relative3d_residual_m(keypoints: Tensor, track: Track, hips: list[int], scale: Tensor,
                          model_size: bool = True) -> Tensor:
    """[T, K] metres: keypoints [T, K, 3] (world units) relative to the mid point of the ``hips`` keypoints,
    turned into each frame's camera axes and divided by ``scale`` (world units per metre of body), against
    the track's metric relative3d; times one factor for the whole track, the least-squares one (confidence
    weighted), unless ``model_size`` (the model's metric size is trusted)."""
    in_camera = torch.einsum("tij,tkj->tki", track.R, keypoints)
    relative = (in_camera - in_camera[:, hips].mean(1, keepdim=True)) / scale
    said = track.relative3d
    if not model_size:
        weight = track.relative3d_weight[..., None]
        said = said * (weight * relative * said).sum() / (weight * said.square()).sum().clamp(min=1e-12)
    return (relative - said).norm(dim=-1)


def data_energy(residual_m: Tensor, weight: Tensor, noise_m: float, robust_m: float) -> Tensor:
    """residuals [T, K] metres, weights [T, K] -> [T] robust data energy per frame."""
    squared = residual_m.square()
    return (weight * (robust_m**2 / noise_m**2) * squared / (squared + robust_m**2)).sum(-1)


def speed_energy(points: Tensor, times_s: Tensor, frame_ids: Tensor, sigma_m_s: float, max_gap_frames: int) -> Tensor:
    """Squared speed of points [T, 3] (metres) between consecutive frames at most max_gap_frames
    apart, over sigma^2."""
    if len(times_s) < 2:
        return points.new_zeros(())
    keep = ((frame_ids[1:] - frame_ids[:-1]) <= max_gap_frames).to(points.dtype)
    velocity = (points[1:] - points[:-1]) / (times_s[1:] - times_s[:-1])[:, None]
    return (keep * velocity.square().sum(-1)).sum() / sigma_m_s**2


def motion_stride(times_s: Tensor, rate_hz: float) -> int:
    """Every how many frames a path sampled at ``times_s`` [T] (seconds) is about ``rate_hz`` apart (at least 1)."""
    if len(times_s) < 2:
        return 1
    frame_rate = 1.0 / float(torch.median(times_s[1:] - times_s[:-1]).clamp(min=1e-9))
    return max(1, round(frame_rate / rate_hz))


def speed_limit_energy(points: Tensor, times_s: Tensor, frame_ids: Tensor, limit_m_s: float, sigma_m_s: float,
                       span_s: float, max_gap_frames: int) -> Tensor:
    """Squared excess of the speed of points [T, 3] (metres) over ``limit_m_s``, over ``sigma_m_s``^2, summed
    over the pairs of frames k apart at most ``max_gap_frames`` frame ids apart, k the number of frames that
    span about ``span_s`` seconds at the track's median frame interval (at least 1): between the consecutive
    frames of a fast video a fit's jitter of a few centimetres would read as speed."""
    if len(times_s) < 2:
        return points.new_zeros(())
    step = motion_stride(times_s, 1.0 / span_s if span_s > 0 else math.inf)
    if len(times_s) <= step:
        step = len(times_s) - 1
    keep = ((frame_ids[step:] - frame_ids[:-step]) <= max_gap_frames).to(points.dtype)
    velocity = (points[step:] - points[:-step]) / (times_s[step:] - times_s[:-step])[:, None]
    speed = (velocity.square().sum(-1) + SPEED_EPSILON).sqrt()
    return (keep * torch.relu(speed - limit_m_s).square()).sum() / sigma_m_s**2


def acceleration_energy(joints: Tensor, times_s: Tensor, frame_ids: Tensor, sigma_m_s2: float,
                        max_gap_frames: int) -> Tensor:
    """Squared second derivative of joint positions [T, J, 3] over times [T], over sigma^2."""
    if len(times_s) < 3:
        return joints.new_zeros(())
    h1, h2 = (times_s[1:-1] - times_s[:-2]), (times_s[2:] - times_s[1:-1])
    gaps = frame_ids[1:] - frame_ids[:-1]
    keep = ((gaps[:-1] <= max_gap_frames) & (gaps[1:] <= max_gap_frames)).to(joints.dtype)
    slope1 = (joints[1:-1] - joints[:-2]) / h1[:, None, None]
    slope2 = (joints[2:] - joints[1:-1]) / h2[:, None, None]
    accel = 2 * (slope2 - slope1) / (h1 + h2)[:, None, None]
    return (keep[:, None] * accel.square().sum(-1)).sum() / sigma_m_s2**2


@dataclass(frozen=True)
class FloorContact:
    """The floor term's data: sole landmarks (``soles``, a KeypointBody of glimpse.fit.ground.SOLE_LANDMARKS),
    contact [T, S] (1 where a sole point touches the floor), the noise scales, and ``plane``: the floor
    ``normal . (x - camera_centre) = -camera_height`` as (normal [3], camera_centre [3], camera_height), world
    units; None for planted feet only (a moving camera's people: their feet not sliding while they touch
    the ground, seen from the camera's path, is what pins where they stand)."""

    soles: KeypointBody
    contact: Tensor
    sigma_m: float
    skate_sigma_m_s: float
    plane: tuple[Tensor, Tensor, float] | None

    def energy(self, soles: Tensor, times_s: Tensor, frame_ids: Tensor, max_gap_frames: int,
               units_per_metre: Tensor) -> Tensor:
        """soles [T, S, 3] world points; heights and speeds are judged in metres of body (world units divided
        by the person's ``units_per_metre``, 1 in a metric frame)."""
        energy = soles.new_zeros(())
        if self.plane is not None:
            height = height_above_plane(soles, *self.plane) / units_per_metre  # [T, S]
            on_floor = (self.contact * height.square()).sum()
            below = height.clamp(max=0.0).square().sum()
            energy = (on_floor + below) / self.sigma_m**2
        if len(times_s) >= 2:
            both = self.contact[1:] * self.contact[:-1] * ((frame_ids[1:] - frame_ids[:-1]) <= max_gap_frames)[:, None]
            velocity = (soles[1:] - soles[:-1]) / (times_s[1:] - times_s[:-1])[:, None, None] / units_per_metre
            energy = energy + (both * velocity.square().sum(-1)).sum() / self.skate_sigma_m_s**2
        return energy


@dataclass(frozen=True)
class SilhouetteTerm:
    """The silhouette term's data (glimpse.fit.silhouette): the surface points, the masks' evidence, each
    point's linked keypoints [S, L] (it counts in a frame only where all of them are seen), ``weight`` (as if so
    many keypoints), the noise and robust scales and the outline's tolerance, metres at the person."""

    surface: SurfaceBody
    evidence: SilhouetteEvidence
    links: Tensor
    weight: float
    noise_m: float
    robust_m: float
    tolerance_m: float

    def per_frame(self, state: FitState, track: Track, depth_ref: Tensor, robust_factor: float) -> Tensor:
        """[T] the term on the evidence's frames (0 on the others)."""
        rows = self.evidence.rows
        points = self.surface(state.betas, state.global_orient[rows], state.body_pose[rows], state.transl[rows],
                              state.log_scale.exp())
        K = track.K[rows]
        pixels, depth = project(points, K, track.R[rows], track.t[rows])
        outside_px, coverage_px, inside = silhouette_residuals_px(self.evidence, pixels, depth)
        metres_per_px = (depth_ref[rows] / (0.5 * (K[:, 0, 0] + K[:, 1, 1])))[:, None]
        seen = ((track.weight[rows][:, self.links] > 0).all(-1) & inside).to(points.dtype)
        outline = self.evidence.edge_weight * inside.any(-1, keepdim=True)
        robust = self.robust_m * robust_factor
        outside = data_energy(outside_px * metres_per_px, seen, self.noise_m, robust) / seen.sum(-1).clamp(min=1)
        uncovered = torch.relu(coverage_px * metres_per_px - self.tolerance_m)
        coverage = data_energy(uncovered, outline, self.noise_m, robust) / outline.sum(-1).clamp(min=1)
        used = self.weight * self.evidence.frame_weight * (outside + coverage)
        return torch.zeros(len(track.frame_ids), dtype=used.dtype).index_add(0, rows, used)


class FitEnergy:
    """E(state) for a person's track; ``terms`` returns each term (for the report), ``__call__`` the sum."""

    def __init__(self, body: KeypointBody, track: Track, prior: PosePrior | PartedPosePrior, limits: JointLimits,
                 weights: FitWeights, max_gap_frames: int):
        self.body, self.track, self.prior, self.limits, self.weights = body, track, prior, limits, weights
        self.max_gap_frames = max_gap_frames  # smoothness links frames at most this far apart
        self.depth_ref: Tensor | None = None  # [T] for 2D: set by update_depth_reference
        self.pose_prior_scale = 1.0  # annealing multipliers of the pose prior's weight ...
        self.robust_scale_factor = 1.0  # ... and of the robust scale
        self.use_priors = True  # False in the global stage (pose and shape are held fixed there)
        self.use_speed = False  # the speed prior, on when the scale is fitted (it is what fixes it)
        self.floor: FloorContact | None = None  # the common floor, set for the ground refit
        self.silhouette: SilhouetteTerm | None = None  # the masks' outline (2D tracks of people with masks)
        self.size_target = TEMPLATE_SIZE  # what the size prior pulls towards: a stated height's size in its refit
        self.frames_independent = False  # True: only the per-frame terms (a batch of pose hypotheses)
        self.hips = [body.names.index(name) for name in HIP_NAMES if name in body.names]

    @property
    def uses_metric_3d(self) -> bool:
        """The track carries metric 3D keypoints and the layout has the hips they are measured from."""
        return self.track.relative3d is not None and len(self.hips) == len(HIP_NAMES)

    @property
    def size_unobserved(self) -> bool:
        """Nothing but the proportions tells this track's body size: 2D keypoints without metric 3D ones whose
        size is trusted (``relative3d_size: model``)."""
        metric_size = self.uses_metric_3d and self.weights.relative3d_size == "model"
        return self.track.is_2d and not metric_size

    @property
    def holds_size(self) -> bool:
        """The size prior is on for this track: its size is unobserved and ``size_sigma`` is above 0."""
        return self.weights.size_sigma > 0 and self.size_unobserved

    def posed(self, state: FitState):
        return self.body(state.betas, state.global_orient, state.body_pose, state.transl, state.log_scale.exp())

    def update_depth_reference(self, state: FitState) -> None:
        """Depth of each frame's body (mean over its keypoints) in the camera, held fixed while minimising."""
        if self.track.is_2d:
            with torch.no_grad():
                _, depth = project(self.posed(state).keypoints, self.track.K, self.track.R, self.track.t)
                self.depth_ref = depth.mean(1).clamp(min=MIN_CAMERA_DEPTH)

    def data_per_frame(self, state: FitState, keypoints: Tensor | None = None) -> Tensor:
        """[T] data energy of each frame (keypoints [T, K, 3] when already posed): the keypoints', plus the
        metric 3D term where the track has it."""
        keypoints = self.posed(state).keypoints if keypoints is None else keypoints
        energy = self.keypoint_data_per_frame(keypoints)
        metric = self.relative3d_per_frame(state, keypoints)
        return energy if metric is None else energy + metric

    def keypoint_data_per_frame(self, keypoints: Tensor) -> Tensor:
        """[T] the keypoints' robust data energy of posed keypoints [T, K, 3]."""
        w = self.weights
        residual = keypoint_residual_m(keypoints, self.track, self.depth_ref)
        robust_m = w.robust_scale_m if self.track.is_2d else w.robust_scale_3d_m
        return data_energy(residual, self.track.weight, w.keypoint_noise_m, robust_m * self.robust_scale_factor)

    def relative3d_per_frame(self, state: FitState, keypoints: Tensor) -> Tensor | None:
        """[T] the metric 3D term of posed keypoints [T, K, 3], or None when the track has no metric keypoints
        (or the layout no hips to measure them from)."""
        track, w = self.track, self.weights
        if not self.uses_metric_3d:
            return None
        relative = relative3d_residual_m(keypoints, track, self.hips, state.log_scale.exp(), w.relative3d_size == "model")
        return data_energy(relative, track.relative3d_weight, w.relative3d_noise_m,
                           w.relative3d_robust_m * self.robust_scale_factor)

    def frame_terms(self, state: FitState, keypoints: Tensor | None = None) -> dict[str, Tensor]:
        """The terms that belong to one frame each, [T] per term, unweighted: data, metric 3D (where the track
        has it), and with the priors on, the pose prior and the joint limits (``terms`` weighs them)."""
        keypoints = self.posed(state).keypoints if keypoints is None else keypoints
        terms = {"data": self.keypoint_data_per_frame(keypoints)}
        metric = self.relative3d_per_frame(state, keypoints)
        if metric is not None:
            terms["metric_3d"] = metric
        if self.use_priors:
            terms["pose_prior"] = self.prior.energy(state.body_pose)
            terms["joint_limits"] = self.limits.energy(state.body_pose)
        if self.silhouette is not None and self.use_priors and not self.frames_independent:
            terms["silhouette"] = self.silhouette.per_frame(state, self.track, self.depth_ref, self.robust_scale_factor)
        return terms

    def frame_energy(self, state: FitState, keypoints: Tensor | None = None) -> Tensor:
        """[T] the weighted sum of frame_terms per frame (keypoints [T, K, 3] when already posed)."""
        weights = self.frame_weights()
        return sum(weights[name] * value for name, value in self.frame_terms(state, keypoints).items())

    def frame_weights(self) -> dict[str, float]:
        """The multipliers of frame_terms' terms (the pose prior's with its annealing)."""
        w = self.weights
        return {"data": 1.0, "metric_3d": 1.0, "pose_prior": w.pose_prior * self.pose_prior_scale,
                "joint_limits": w.joint_limits, "silhouette": 1.0}

    def terms(self, state: FitState) -> dict[str, Tensor]:
        """Every term, summed over the frames (``frames_independent``: only those of frame_terms)."""
        w = self.weights
        out = self.posed(state)
        weights = self.frame_weights()
        terms = {name: weights[name] * value.sum() for name, value in self.frame_terms(state, out.keypoints).items()}
        if self.use_priors and not self.frames_independent:
            terms["shape_prior"] = w.shape_prior * shape_energy(state.betas)
            if self.holds_size:
                terms["size_prior"] = len(self.track.times_s) * size_energy(self.body.size_ratio(state.betas),
                                                                            self.size_target, w.size_sigma)
            metres = out.joints / state.log_scale.exp()  # motion is judged in metres of body
            # ... and accelerations of a body the template's size: otherwise shrinking everyone towards the
            # camera, which 2D keypoints cannot see, would lower the smoothness term.
            template_metres = metres / self.body.size_ratio(state.betas)
            terms["smoothness"] = acceleration_energy(template_metres, self.track.times_s, self.track.frame_ids,
                                                      w.accel_sigma_m_s2, self.max_gap_frames)
            if self.use_speed:
                terms["speed"] = speed_energy(metres[:, 0], self.track.times_s, self.track.frame_ids,
                                              w.speed_sigma_m_s, self.max_gap_frames)
            if w.speed_limit_m_s > 0:
                terms["speed_limit"] = speed_limit_energy(metres[:, 0], self.track.times_s, self.track.frame_ids,
                                                          w.speed_limit_m_s, w.speed_limit_sigma_m_s,
                                                          w.speed_limit_span_s, self.max_gap_frames)
            if self.floor is not None:
                soles = self.floor.soles(state.betas, state.global_orient, state.body_pose, state.transl,
                                         state.log_scale.exp()).keypoints
                terms["floor"] = self.floor.energy(soles, self.track.times_s, self.track.frame_ids,
                                                   self.max_gap_frames, state.log_scale.exp())
        return terms

    def __call__(self, state: FitState) -> Tensor:
        return sum(self.terms(state).values())
