"""One person as canonical Gaussians driven by SMPL pose (paper Sec. 4.3).

The person's Gaussians live in the canonical body frame (metres, SMPL axes: y up, facing +z)
around that person's body in the Da-pose. In frame t they move by the skinning grid and the
frame's pose: ``A = (sum_j w_j P_j) (sum_j w_j C_j)^-1`` per Gaussian (glimpse.body.skinning),
means ``A mu``, covariances ``A Σ Aᵀ``; spherical harmonics are evaluated for the view direction
rotated into the canonical frame by the polar (closest-rotation) part of A (CONTRACTS.md).
Optional per-frame pose refinement adds a learnt axis-angle offset to each frame's pose.

Once training is over (rendering a finished run), ``freeze()`` caches what no frame changes (skin
weights, the canonical blends' inverses, canonical covariances, SH); ``posed`` without gradients then
takes the C++ kernel (csrc/pose_cpu.cpp) on CPU, or the same maths in PyTorch elsewhere.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor, nn

from glimpse.body.lbs import batch_rigid_transform, batch_rodrigues
from glimpse.body.model import BodyModel, scaled_translated
from glimpse.body.params import BodyParams
from glimpse.body.skinning import (
    SkinWeightGrid, bake_skin_weight_grid, blend_transforms, canonical_body_pose, canonical_to_posed,
    deform_gaussians, invert_affine,
)
from glimpse.gaussians.model import GaussianModel, knn_scales
from glimpse.humans.posing_cpu import pose_gaussians_cpu
from glimpse.render.projection import quat_scale_to_covariance
from glimpse.render.sh import num_sh_coeffs, rotate_view_dirs, sh_to_rgb

POSE_DIM = 72  # global_orient (3) + body_pose (69), axis-angle
SCALE_FLOOR_M = 1e-3  # metres: smallest initial Gaussian scale (coincident vertices)
POLAR_ITERATIONS = 6  # Newton steps of the polar decomposition (error below 1e-6 for blends of bone rotations)
DET_FLOOR = 1e-12  # determinants are clamped to this (a collapsed blend has no meaningful rotation)


@dataclass(frozen=True)
class BodyRig:
    """What posing needs of one person's body, fixed over a run.

    rest_joints [24, 3]: the shaped rest-pose joints (metres, model frame); parents: the joint tree;
    canonical_transforms [24, 4, 4]: the joints' skinning transforms in the Da-pose (scale 1, no
    translation), C_j above; canonical_vertices [V, 3]: the body in the Da-pose (metres).
    """

    rest_joints: Tensor
    parents: tuple[int, ...]
    canonical_transforms: Tensor
    canonical_vertices: Tensor


def build_rig(body_model: BodyModel, betas: np.ndarray, hip_angle_deg: float) -> BodyRig:
    """The person's rig from the body model, their shape ``betas [10]`` and the Da-pose angle."""
    with torch.no_grad():
        out = body_model(torch.as_tensor(betas[None]), torch.zeros(1, 3),
                         torch.as_tensor(canonical_body_pose(hip_angle_deg)[None]))
    return BodyRig(out.rest_joints[0].float(), tuple(int(p) for p in body_model.parents),
                   out.transforms[0].float(), out.vertices[0].float())


def joint_transforms(rig: BodyRig, pose: Tensor, transl: Tensor, scale: float) -> Tensor:
    """The 24 skinning transforms [24, 4, 4] of the body posed by ``pose [72]`` (axis-angle, root first),
    then scaled and moved by ``transl [3]``: BodyModel.forward's ``transforms`` without its vertices."""
    rotations = batch_rodrigues(pose.reshape(1, -1, 3))
    _, transforms = batch_rigid_transform(rotations, rig.rest_joints[None].to(pose), rig.parents)
    return scaled_translated(transforms, torch.full((1,), scale, dtype=pose.dtype, device=pose.device),
                             transl.reshape(1, 3))[0]


def polar_rotation(matrices: Tensor) -> Tensor:
    """[N, 3, 3] invertible matrices with positive determinant -> their closest rotations [N, 3, 3] (the
    orthogonal polar factor), by Newton's iteration X <- (X + X^-T) / 2 from X / det(X)^(1/3), which
    converges quadratically; X^-T is the cofactor matrix over the determinant. No gradient. By the C++ kernel
    for float32 CPU tensors where it builds (the same iteration)."""
    from glimpse.render.composite_cpu import extension, kernel_applies

    if kernel_applies(matrices):
        return extension().polar_rotations(matrices.detach().contiguous())
    with torch.no_grad():
        x = matrices / torch.linalg.det(matrices).abs().clamp(min=DET_FLOOR).pow(1.0 / 3.0)[:, None, None]
        for _ in range(POLAR_ITERATIONS):
            rows = x.unbind(dim=1)  # three [N, 3]
            cofactors = torch.stack([torch.linalg.cross(rows[1], rows[2]), torch.linalg.cross(rows[2], rows[0]),
                                     torch.linalg.cross(rows[0], rows[1])], dim=1)
            det = (rows[0] * cofactors[:, 0]).sum(-1)
            x = 0.5 * (x + cofactors / det.clamp(min=DET_FLOOR)[:, None, None])
        return x


def view_colours(blended: Tensor, means: Tensor, camera_centre: Tensor, degree: int, sh: Tensor) -> Tensor:
    """[N, 3] colours of posed Gaussians (``blended [N, 4, 4]``, posed ``means [N, 3]``) seen from ``camera_centre``:
    SH ``sh [N, K, 3]`` up to ``degree``, the view direction rotated into the canonical frame (CONTRACTS.md)."""
    dirs = means - camera_centre
    if degree > 0:
        dirs = rotate_view_dirs(dirs, polar_rotation(blended[:, :3, :3]))
    return sh_to_rgb(degree, sh[:, : num_sh_coeffs(degree)], dirs)


@dataclass
class PosedGaussians:
    """A person's Gaussians in one frame, ready for the rasterizer (world frame)."""

    means: Tensor  # [N, 3]
    covariances: Tensor  # [N, 3, 3]
    opacities: Tensor  # [N]
    colors: Tensor  # [N, 3]


@dataclass(frozen=True)
class FrozenPosing:
    """Per-Gaussian quantities of a trained person that no frame changes: skin weights [N, J], the inverse of
    the canonical blend (sum_j w_j C_j)^-1 [N, 4, 4], canonical covariances [N, 3, 3], SH [N, K, 3] and
    opacities [N]."""

    weights: Tensor
    canonical_inverse: Tensor
    covariances: Tensor
    sh: Tensor
    opacities: Tensor


class PersonGaussians(nn.Module):
    """A person: canonical Gaussians (``model``), their skinning grid and rig, and the body
    parameters of every frame (``body``), with an optional learnt pose offset per frame."""

    def __init__(self, pid: str, model: GaussianModel, grid: SkinWeightGrid, rig: BodyRig, body: BodyParams):
        super().__init__()
        self.pid, self.model, self.grid, self.rig, self.body = pid, model, grid, rig, body
        self.row_of_frame = {int(f): row for row, f in enumerate(body.frame_ids)}
        self.base_pose = torch.as_tensor(np.concatenate([body.global_orient, body.body_pose], axis=1),
                                         dtype=torch.float32)  # [T, 72]
        self.transl = torch.as_tensor(body.transl, dtype=torch.float32)  # [T, 3]
        self.pose_offsets = nn.Parameter(torch.zeros(len(body.frame_ids), POSE_DIM))  # [T, 72] radians
        self.frozen: FrozenPosing | None = None

    def to(self, *args, **kwargs) -> "PersonGaussians":
        module = super().to(*args, **kwargs)
        device = module.pose_offsets.device
        self.base_pose, self.transl = self.base_pose.to(device), self.transl.to(device)
        self.grid = SkinWeightGrid(self.grid.weights.to(device), self.grid.bounds_min.to(device),
                                   self.grid.bounds_max.to(device))
        self.rig = BodyRig(self.rig.rest_joints.to(device), self.rig.parents,
                           self.rig.canonical_transforms.to(device), self.rig.canonical_vertices.to(device))
        if self.frozen is not None:
            self.freeze()
        return module

    @torch.no_grad()
    def freeze(self) -> PersonGaussians:
        """Cache what posing needs that no frame changes, for rendering only (training must not follow: the
        cache would go stale). Returns self."""
        weights = self.grid.lookup(self.model.means).contiguous()
        self.frozen = FrozenPosing(
            weights, invert_affine(blend_transforms(weights, self.rig.canonical_transforms)).contiguous(),
            quat_scale_to_covariance(self.model.quats, self.model.scales()).contiguous(),
            self.model.sh().contiguous(), self.model.opacities().contiguous())
        return self

    @property
    def scale(self) -> float:
        """World units per metre of this person's body."""
        return float(self.body.scale)

    def in_frame(self, frame_id: int) -> bool:
        return int(frame_id) in self.row_of_frame

    def pose(self, frame_id: int) -> Tensor:
        """[72] the frame's pose including the learnt offset."""
        row = self.row_of_frame[int(frame_id)]
        return self.base_pose[row] + self.pose_offsets[row]

    def frame_transforms(self, frame_id: int) -> Tensor:
        """[24, 4, 4] the joints' skinning transforms in ``frame_id`` (refined pose, scale, translation)."""
        row = self.row_of_frame[int(frame_id)]
        return joint_transforms(self.rig, self.pose(frame_id), self.transl[row], self.scale)

    def blended_transforms(self, frame_id: int) -> Tensor:
        """[N, 4, 4] canonical-to-world transform of each Gaussian in ``frame_id``."""
        posed = self.frame_transforms(frame_id)
        weights = self.grid.lookup(self.model.means)
        return canonical_to_posed(weights, posed, self.rig.canonical_transforms)

    def posed(self, frame_id: int, camera_centre: Tensor, sh_degree: int) -> PosedGaussians:
        """The Gaussians in ``frame_id`` seen from ``camera_centre [3]`` (world), colours up to ``sh_degree``."""
        degree = min(sh_degree, self.model.sh_degree)
        if self.frozen is not None and not torch.is_grad_enabled():
            return self._posed_frozen(frame_id, camera_centre, degree)
        return self.posed_with(self.frame_transforms(frame_id), camera_centre, degree)

    def posed_with(self, transforms: Tensor, camera_centre: Tensor, sh_degree: int) -> PosedGaussians:
        """The Gaussians posed by the joints' skinning ``transforms [24, 4, 4]`` (any pose: a frame's, a new one
        from joint_transforms, or the canonical rig.canonical_transforms), seen from ``camera_centre [3]`` in
        the frame those transforms map into; differentiable in every Gaussian parameter."""
        from glimpse.render.composite_cpu import kernel_applies

        degree = min(sh_degree, self.model.sh_degree)
        covariances = quat_scale_to_covariance(self.model.quats, self.model.scales())
        if kernel_applies(self.model.means, transforms, self.grid.weights):  # the same maths in one C++ pass
            means, covariances, dirs = pose_gaussians_cpu(self.model.means, covariances, transforms, self.grid,
                                                          self.rig.canonical_transforms, camera_centre)
            colours = sh_to_rgb(degree, self.model.sh()[:, : num_sh_coeffs(degree)], dirs)
            return PosedGaussians(means, covariances, self.model.opacities(), colours)
        blended = canonical_to_posed(self.grid.lookup(self.model.means), transforms, self.rig.canonical_transforms)
        means, covariances = deform_gaussians(self.model.means, covariances, blended)
        colours = view_colours(blended, means, camera_centre, degree, self.model.sh())
        return PosedGaussians(means, covariances, self.model.opacities(), colours)

    def _posed_frozen(self, frame_id: int, camera_centre: Tensor, degree: int) -> PosedGaussians:
        """posed() from the frozen cache: the C++ kernel on CPU when it builds, else PyTorch (same maths)."""
        from glimpse.render import composite_cpu

        posed = self.frame_transforms(frame_id)
        cache, means = self.frozen, self.model.means.detach()
        if means.device.type == "cpu" and composite_cpu.available():
            means, covariances, colours = composite_cpu.extension().pose_forward(
                cache.weights, posed.float().contiguous(), cache.canonical_inverse, means, cache.covariances,
                cache.sh, degree, camera_centre.float().contiguous())
        else:
            blended = blend_transforms(cache.weights, posed) @ cache.canonical_inverse
            means, covariances = deform_gaussians(means, cache.covariances, blended)
            colours = view_colours(blended, means, camera_centre, degree, cache.sh)
        return PosedGaussians(means, covariances, cache.opacities, colours)

    def refined_body(self) -> BodyParams:
        """The body parameters with the learnt pose offsets added (stage 06's body.npz)."""
        pose = (self.base_pose + self.pose_offsets.detach()).cpu().double().numpy()
        b = self.body
        return BodyParams(b.frame_ids, b.betas, pose[:, :3], pose[:, 3:], b.transl, b.scale, b.body_model,
                          b.interpolated)


def initial_person(pid: str, body_model: BodyModel, body: BodyParams, hip_angle_deg: float, skinning,
                   grey: float, opacity: float, knn: int, sh_degree: int) -> PersonGaussians:
    """Canonical Gaussians on the Da-pose body vertices of the person's shape: one per vertex, grey,
    isotropic with 3DGS's kNN scale, one opacity (paper: 0.9); skin weights baked from the same body."""
    rig = build_rig(body_model, body.betas, hip_angle_deg)
    vertices = rig.canonical_vertices.double().numpy()
    grid = bake_skin_weight_grid(vertices, body_model.weights.double().numpy(), skinning.grid_resolution,
                                 skinning.grid_margin_m, skinning.knn, skinning.idw_power)
    scales = torch.as_tensor(knn_scales(vertices, knn, SCALE_FLOOR_M))
    model = GaussianModel.from_points(rig.canonical_vertices, torch.full((len(vertices), 3), grey), scales,
                                      opacity, sh_degree)
    return PersonGaussians(pid, model, grid, rig, body)
