"""Offline priors for body fitting: no downloaded GMM or VPoser weights.

- **Pose prior**: Gaussians over the 69 body-pose numbers fitted to the poses of the given motions
  (built-in procedural ones, plus any AMASS- or smplx-style .npz the user lists) and their
  left-right mirror images, with an isotropic floor variance added so that poses the motions never
  show stay reachable: one Gaussian over all (``mixture=False``, pipeline.yaml's default) or one per
  motion (their equal-weight mixture). The energy is the negative log-likelihood times 2: for one
  Gaussian, the squared Mahalanobis distance. One Gaussian puts a crouch and a walk in one blob
  whose centre is neither and pulls both towards it; the mixture does not, but measured worse on
  the fixtures' waving people (docs/fitting.md). Either knows only what the motions do.
- **Joint limits**: the hinge joints (knees, elbows) bend one way only; a squared penalty on the
  axis-angle components outside anatomical ranges (as SMPLify's angle prior, with bounds).
- **Shape prior**: betas are unit-variance coefficients; energy ``|betas|^2``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from glimpse.body.motion import BUILTIN_MOTIONS, SMPL_BODY_JOINTS, builtin_motion, load_motion
from glimpse.fit.sampling import farthest_point_samples

PRIOR_FPS = 30.0  # built-in motions are sampled at this rate ...
PRIOR_SECONDS = 4.0  # ... over this long (a few cycles of each)
_MIRROR_ROTVEC = np.array([1.0, -1.0, -1.0])  # reflection x -> -x of a rotation vector (body left = +x)

# (joint, axis, lowest, highest) in degrees, SMPL local axes (y up, facing +z, left = +x).
# Knee flexion is +x; left elbow flexion is -y, right +y (the forearm swings forward).
JOINT_LIMITS_DEG: tuple[tuple[str, str, float, float], ...] = (
    ("left_knee", "x", -5.0, 150.0), ("right_knee", "x", -5.0, 150.0),
    ("left_knee", "y", -15.0, 15.0), ("right_knee", "y", -15.0, 15.0),
    ("left_knee", "z", -15.0, 15.0), ("right_knee", "z", -15.0, 15.0),
    ("left_elbow", "y", -150.0, 5.0), ("right_elbow", "y", -5.0, 150.0),
    ("left_elbow", "z", -15.0, 15.0), ("right_elbow", "z", -15.0, 15.0),
)


def mirror_body_pose(body_pose: np.ndarray) -> np.ndarray:
    """[N, 69] poses -> their left-right mirror images (joints swapped, rotations reflected in x)."""
    joints = body_pose.reshape(len(body_pose), len(SMPL_BODY_JOINTS), 3)
    index = {name: i for i, name in enumerate(SMPL_BODY_JOINTS)}
    swap = [index[_other_side(name)] for name in SMPL_BODY_JOINTS]
    return (joints[:, swap] * _MIRROR_ROTVEC).reshape(body_pose.shape)


def _other_side(name: str) -> str:
    for a, b in (("left_", "right_"), ("right_", "left_")):
        if name.startswith(a):
            return b + name[len(a):]
    return name


def motion_poses(sources: list[str]) -> np.ndarray:
    """[N, 69] body poses of the listed motions: built-in names or paths of motion .npz files."""
    poses = []
    for source in sources:
        if source in BUILTIN_MOTIONS:
            poses.append(builtin_motion(source, int(PRIOR_FPS * PRIOR_SECONDS), PRIOR_FPS).body_pose)
        else:
            poses.append(load_motion(Path(source)).body_pose)
    return np.concatenate(poses)


def representative_poses(sources: list[str], count: int) -> np.ndarray:
    """[count, 69] poses spread over the listed motions' poses and their mirror images: their mean first,
    then each next the pose farthest (axis-angle distance) from those already taken. Where a fit from
    2D keypoints starts its pose hypotheses (a crouch whose thighs point at the camera is a saddle of
    the 2D energy for a body started standing: bending towards the camera moves no keypoint at first).
    Deterministic."""
    poses = motion_poses(sources)
    poses = np.concatenate([poses, mirror_body_pose(poses)])
    mean = poses.mean(0)
    spread = farthest_point_samples(poses, max(count - 1, 0), np.linalg.norm(poses - mean, axis=1))
    return np.concatenate([mean[None], poses[spread]])


@dataclass(frozen=True)
class PosePrior:
    """A mixture of Gaussians over body_pose, equal weights. means [C, 69] radians; whitenings
    [C, 69, 69] with ``whitening.T @ whitening = inverse covariance``; log_det_excess [C]: each
    component's log-determinant of covariance above the smallest one's. ``mean`` [69] is the mean of
    all the poses (where fits start). description says what it was fitted to."""

    means: Tensor
    whitenings: Tensor
    log_det_excess: Tensor
    mean: Tensor
    description: str

    def energy(self, body_pose: Tensor) -> Tensor:
        """[T, 69] -> [T] the mixture's negative log-likelihood times 2, up to a constant:
        ``-2 log sum_c exp(-(d_c^2 + log_det_excess_c) / 2)``, d_c the Mahalanobis distance to component c
        (the squared Mahalanobis distance itself for one component)."""
        offsets = body_pose[:, None] - self.means  # [T, C, 69]
        squared = torch.einsum("cij,tcj->tci", self.whitenings, offsets).square().sum(-1)  # [T, C]
        return -2.0 * torch.logsumexp(-0.5 * (squared + self.log_det_excess), dim=-1)


@dataclass(frozen=True)
class PartedPosePrior:
    """Independent priors over parts of body_pose: ``parts`` pairs each prior with the indices [D] of the 69
    numbers it covers; the energy is their sum. ``mean`` [69] and ``description`` as PosePrior's."""

    parts: tuple[tuple[Tensor, PosePrior], ...]
    mean: Tensor
    description: str

    def energy(self, body_pose: Tensor) -> Tensor:
        """[T, 69] -> [T]"""
        return sum(prior.energy(body_pose[:, index]) for index, prior in self.parts)


def pose_indices(joints: tuple[str, ...]) -> np.ndarray:
    """Indices into body_pose (69) of the rotations of the named SMPL body joints."""
    return np.array([3 * SMPL_BODY_JOINTS.index(name) + axis for name in joints for axis in range(3)])


def build_parted_pose_prior(sources: list[str], floor_deg: float, mixture_joints: tuple[str, ...],
                            dtype: torch.dtype = torch.float64) -> PartedPosePrior:
    """A mixture (one Gaussian per motion) over the rotations of ``mixture_joints`` (for example the legs:
    a crouch is not pulled towards the average of crouching and walking), one Gaussian over the other joints
    (a waving arm keeps the broad pull of the single Gaussian)."""
    mixed = pose_indices(mixture_joints)
    rest = np.setdiff1d(np.arange(3 * len(SMPL_BODY_JOINTS)), mixed)
    parts = ((torch.as_tensor(mixed), build_pose_prior(sources, floor_deg, dtype, True, mixed)),
             (torch.as_tensor(rest), build_pose_prior(sources, floor_deg, dtype, False, rest)))
    mean = torch.empty(3 * len(SMPL_BODY_JOINTS), dtype=dtype)
    for index, prior in parts:  # each part's mean is the mean of all the poses over its numbers
        mean[index] = prior.mean
    description = (f"a mixture of {len(sources)} Gaussians (one per motion) over the rotations of "
                   f"{', '.join(mixture_joints)}, one Gaussian over the other joints, fitted to "
                   f"{parts[1][1].description.split(' fitted to ', 1)[1]}")
    return PartedPosePrior(parts, mean, description)


def build_pose_prior(sources: list[str], floor_deg: float, dtype: torch.dtype = torch.float64,
                     mixture: bool = True, index: np.ndarray | None = None) -> PosePrior:
    """Fit one Gaussian per motion (``mixture``) or one over all of them, to the motions' poses and their
    mirror images (the numbers ``index`` of body_pose, all 69 when None); ``floor_deg`` is the standard
    deviation of the isotropic variance added to every component's covariance."""
    if not sources:
        raise ValueError("build_pose_prior: name at least one motion")
    groups = [[source] for source in sources] if mixture else [list(sources)]
    means, whitenings, log_dets, everything = [], [], [], []
    for group in groups:
        poses = motion_poses(group)
        samples = np.concatenate([poses, mirror_body_pose(poses)])
        if index is not None:
            samples = samples[:, index]
        covariance = np.cov(samples, rowvar=False) + math.radians(floor_deg) ** 2 * np.eye(samples.shape[1])
        cholesky = np.linalg.cholesky(covariance)
        means.append(samples.mean(0))
        whitenings.append(np.linalg.inv(cholesky))  # L^-1: |L^-1 x|^2 = x^T C^-1 x
        log_dets.append(2.0 * np.log(np.diag(cholesky)).sum())
        everything.append(samples)
    log_dets = np.array(log_dets)
    count = sum(len(s) for s in everything)
    kind = f"a mixture of {len(groups)} Gaussians (one per motion)" if mixture else "one Gaussian"
    description = (f"{kind} over body_pose fitted to {count} poses of {', '.join(sources)} and their mirror "
                   f"images, plus an isotropic {floor_deg} degree floor")
    as_tensor = lambda x: torch.as_tensor(np.asarray(x), dtype=dtype)  # noqa: E731
    return PosePrior(as_tensor(means), as_tensor(whitenings), as_tensor(log_dets - log_dets.min()),
                     as_tensor(np.concatenate(everything).mean(0)), description)


@dataclass(frozen=True)
class JointLimits:
    """Box bounds on axis-angle components: index [L] into body_pose (69), low/high [L] radians."""

    index: Tensor
    low: Tensor
    high: Tensor

    def energy(self, body_pose: Tensor) -> Tensor:
        """[T, 69] -> [T] sum of squared excursions outside the bounds (radians^2)."""
        values = body_pose[:, self.index]
        return ((self.low - values).clamp(min=0).square() + (values - self.high).clamp(min=0).square()).sum(-1)


def joint_limits(dtype: torch.dtype = torch.float64) -> JointLimits:
    joint_index = {name: i for i, name in enumerate(SMPL_BODY_JOINTS)}
    index = [3 * joint_index[joint] + "xyz".index(axis) for joint, axis, _, _ in JOINT_LIMITS_DEG]
    low = [math.radians(lo) for _, _, lo, _ in JOINT_LIMITS_DEG]
    high = [math.radians(hi) for _, _, _, hi in JOINT_LIMITS_DEG]
    return JointLimits(torch.tensor(index), torch.tensor(low, dtype=dtype), torch.tensor(high, dtype=dtype))


def shape_energy(betas: Tensor) -> Tensor:
    """[10] -> [] squared norm of the shape coefficients."""
    return betas.square().sum()


def size_energy(size_ratio: Tensor, target: float, sigma: float) -> Tensor:
    """[] ``(log(size_ratio / target) / sigma)^2``: a body's size (over the template's, [] tensor) held to
    ``target`` with a relative standard deviation ``sigma``."""
    return ((size_ratio / target).log() / sigma).square()
