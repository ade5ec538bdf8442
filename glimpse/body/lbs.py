"""Linear blend skinning maths for SMPL-style body models (stateless, batched, differentiable).

Pure functions on torch tensors; no model state. Conventions, shared with smplx:

- rotations are axis-angle vectors (radians) or 3x3 matrices acting on column vectors;
- a pose-corrective feature is ``(R_j - I)`` for every non-root joint, each 3x3
  matrix flattened row-major, joints in order: ``P = 9 * (J - 1)`` numbers (207 for SMPL);
- vertex offsets of blend-shape bases are stored ``[V, 3, K]`` (vertex, xyz, component);
- lengths are in metres.

Shapes are written gsplat-style: ``# [B, V, 3]``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import torch
from torch import Tensor

# Below this squared angle (rad^2) the rotation coefficients use their Taylor series:
# at theta^2 = 1e-4 the first dropped term (theta^6 / 5040) is ~2e-16, below float64 eps.
_TAYLOR_MAX_ANGLE_SQ = 1e-4
AFFINE_ENTRIES = 12  # the top 3x4 block of a rigid 4x4 transform


class LbsOutput(NamedTuple):
    """Everything :func:`lbs` computes (posed about the model's own origin, no global transl)."""

    vertices: Tensor  # [B, V, 3] posed vertices
    joints: Tensor  # [B, J, 3] posed joints
    transforms: Tensor  # [B, J, 4, 4] skinning transforms (rest-pose point -> posed point)
    rest_vertices: Tensor  # [B, V, 3] template + shape blend + pose blend
    rest_joints: Tensor  # [B, J, 3] joints of the shaped rest pose


def skew(vectors: Tensor) -> Tensor:
    """Cross-product matrices: ``skew(v) @ u == cross(v, u)``.

    vectors: [..., 3]  ->  [..., 3, 3]
    """
    x, y, z = vectors.unbind(-1)
    zero = torch.zeros_like(x)
    rows = (zero, -z, y, z, zero, -x, -y, x, zero)
    return torch.stack(rows, dim=-1).reshape(*vectors.shape[:-1], 3, 3)


def batch_rodrigues(axis_angle: Tensor) -> Tensor:
    """Rotation matrices from axis-angle vectors (Rodrigues' formula).

    axis_angle: [..., 3], direction = axis, norm = angle in radians.
    Returns [..., 3, 3] with ``R = I + a(t) K + b(t) K^2``, ``K = skew(axis_angle)``,
    ``a = sin(t) / t``, ``b = (1 - cos t) / t^2``. ``b`` is evaluated as
    ``(sin(t/2) / (t/2))^2 / 2`` (no cancellation in float32) and both switch to
    their Taylor series near ``t = 0``, so a zero vector gives exactly the identity,
    and values, first and second derivatives are finite and exact there.
    """
    if axis_angle.shape[-1] != 3:
        raise ValueError(f"batch_rodrigues: axis_angle must be [..., 3], found {tuple(axis_angle.shape)}")
    angle_sq = (axis_angle * axis_angle).sum(dim=-1)[..., None, None]  # [..., 1, 1]
    small = angle_sq < _TAYLOR_MAX_ANGLE_SQ
    safe_angle = torch.sqrt(torch.where(small, torch.ones_like(angle_sq), angle_sq))
    half = 0.5 * safe_angle
    a_exact = torch.sin(safe_angle) / safe_angle
    b_exact = 0.5 * (torch.sin(half) / half) ** 2
    a_taylor = 1.0 - angle_sq / 6.0 + angle_sq * angle_sq / 120.0
    b_taylor = 0.5 - angle_sq / 24.0 + angle_sq * angle_sq / 720.0
    a = torch.where(small, a_taylor, a_exact)
    b = torch.where(small, b_taylor, b_exact)
    k = skew(axis_angle)  # [..., 3, 3]
    eye = torch.eye(3, dtype=axis_angle.dtype, device=axis_angle.device)
    return eye + a * k + b * (k @ k)


def blend_shapes(betas: Tensor, shapedirs: Tensor) -> Tensor:
    """Linear blend-shape offsets ``sum_k betas[b, k] * shapedirs[v, :, k]``.

    betas:     [B, K] coefficients (shape betas; also pose-corrective features with posedirs)
    shapedirs: [V, 3, K] basis, metres per unit coefficient
    Returns    [B, V, 3] metres.
    """
    if betas.ndim != 2 or shapedirs.ndim != 3 or shapedirs.shape[1] != 3:
        raise ValueError(
            f"blend_shapes: need betas [B, K] and shapedirs [V, 3, K], "
            f"found {tuple(betas.shape)} and {tuple(shapedirs.shape)}"
        )
    if betas.shape[1] != shapedirs.shape[2]:
        raise ValueError(f"blend_shapes: {betas.shape[1]} coefficients for a basis of {shapedirs.shape[2]} components")
    num_vertices, _, num_components = shapedirs.shape
    flat_basis = shapedirs.reshape(num_vertices * 3, num_components)  # [V*3, K], a view
    return (betas @ flat_basis.T).reshape(betas.shape[0], num_vertices, 3)


def vertices_to_joints(J_regressor: Tensor, vertices: Tensor) -> Tensor:
    """Joint locations regressed from vertices.

    J_regressor: [J, V] (rows are convex weights for SMPL)
    vertices:    [B, V, 3] metres
    Returns      [B, J, 3] metres.
    """
    if J_regressor.ndim != 2 or vertices.ndim != 3 or J_regressor.shape[1] != vertices.shape[1]:
        raise ValueError(
            f"vertices_to_joints: need J_regressor [J, V] and vertices [B, V, 3], "
            f"found {tuple(J_regressor.shape)} and {tuple(vertices.shape)}"
        )
    return torch.einsum("jv,bvc->bjc", J_regressor, vertices)  # one GEMM, unlike a broadcast matmul


def _parent_list(parents: Tensor | Sequence[int], num_joints: int) -> list[int]:
    """parents as Python ints, checked: [-1, p1, ...] with p_j < j (topological order)."""
    values = [int(p) for p in (parents.tolist() if isinstance(parents, Tensor) else parents)]
    if len(values) != num_joints:
        raise ValueError(f"parents has {len(values)} entries for {num_joints} joints")
    if values[0] != -1 or any(not 0 <= p < j for j, p in enumerate(values) if j > 0):
        raise ValueError(f"parents must be -1 for the root and p < j for joint j, found {values}")
    return values


def _homogeneous(rotations: Tensor, translations: Tensor) -> Tensor:
    """rotations [..., 3, 3], translations [..., 3] -> rigid transforms [..., 4, 4]."""
    top = torch.cat([rotations, translations[..., None]], dim=-1)  # [..., 3, 4]
    bottom = torch.zeros_like(top[..., :1, :])  # [..., 1, 4]
    bottom[..., 0, 3] = 1.0
    return torch.cat([top, bottom], dim=-2)


def batch_rigid_transform(
    rot_mats: Tensor, joints: Tensor, parents: Tensor | Sequence[int]
) -> tuple[Tensor, Tensor]:
    """Forward kinematics of a joint tree.

    rot_mats: [B, J, 3, 3] local rotation of each joint relative to its parent
    joints:   [B, J, 3] rest-pose joint locations, metres
    parents:  [J] parent index of each joint, -1 for the root, parents[j] < j
    Returns
      posed_joints: [B, J, 3] joint locations after posing, metres
      transforms:   [B, J, 4, 4] skinning transforms ``G_j @ translation(-joints_j)``, where
                    ``G_j`` is joint j's world transform: they map a rest-pose point rigidly
                    attached to joint j to its posed location. The root stays at its rest location.
    """
    if rot_mats.ndim != 4 or rot_mats.shape[-2:] != (3, 3) or joints.ndim != 3 or joints.shape[-1] != 3:
        raise ValueError(
            f"batch_rigid_transform: need rot_mats [B, J, 3, 3] and joints [B, J, 3], "
            f"found {tuple(rot_mats.shape)} and {tuple(joints.shape)}"
        )
    if rot_mats.shape[:2] != joints.shape[:2]:
        raise ValueError(
            f"batch_rigid_transform: rot_mats {tuple(rot_mats.shape)} and joints {tuple(joints.shape)} disagree"
        )
    parent_of = _parent_list(parents, joints.shape[1])
    parent_joints = joints[:, [max(p, 0) for p in parent_of]]  # [B, J, 3]
    offsets = torch.cat([joints[:, :1], joints[:, 1:] - parent_joints[:, 1:]], dim=1)  # [B, J, 3]
    local = _homogeneous(rot_mats, offsets)  # [B, J, 4, 4]
    world = [local[:, 0]]
    for j in range(1, len(parent_of)):
        world.append(world[parent_of[j]] @ local[:, j])
    world_transforms = torch.stack(world, dim=1)  # [B, J, 4, 4]
    rotations = world_transforms[..., :3, :3]
    posed_joints = world_transforms[..., :3, 3]
    rest_offset = (rotations @ joints[..., None])[..., 0]  # [B, J, 3]
    return posed_joints, _homogeneous(rotations, posed_joints - rest_offset)


def pose_features(rot_mats: Tensor) -> Tensor:
    """Pose-corrective features: [B, J, 3, 3] -> [B, 9 * (J - 1)], ``(R_j - I)`` for j >= 1."""
    eye = torch.eye(3, dtype=rot_mats.dtype, device=rot_mats.device)
    return (rot_mats[:, 1:] - eye).reshape(rot_mats.shape[0], -1)


def skin_vertices(weights: Tensor, transforms: Tensor, rest_vertices: Tensor) -> Tensor:
    """Linear blend skinning: ``v' = sum_j weights[v, j] * transforms[:, j] @ [v; 1]``.

    weights:       [V, J] skinning weights
    transforms:    [B, J, 4, 4]
    rest_vertices: [B, V, 3] metres
    Returns        [B, V, 3] metres.
    """
    batch, num_joints = transforms.shape[:2]
    affine = transforms[..., :3, :].reshape(batch, num_joints, AFFINE_ENTRIES)  # [B, J, 12]
    blended = torch.einsum("vj,bjk->bvk", weights, affine).reshape(batch, -1, 3, 4)  # [B, V, 3, 4]
    # the blended 3x4 matrix times (x, y, z, 1), column by column as fused multiply-adds: [B, V, 3]
    out = torch.addcmul(blended[..., 3], blended[..., 0], rest_vertices[..., 0:1])
    out = torch.addcmul(out, blended[..., 1], rest_vertices[..., 1:2])
    return torch.addcmul(out, blended[..., 2], rest_vertices[..., 2:3])


def lbs(
    betas: Tensor,
    pose: Tensor,
    v_template: Tensor,
    shapedirs: Tensor,
    posedirs: Tensor,
    J_regressor: Tensor,
    parents: Tensor | Sequence[int],
    weights: Tensor,
    pose2rot: bool = True,
) -> LbsOutput:
    """SMPL forward pass about the model origin (no global translation or scale).

    betas:       [B, S] shape coefficients (S <= shapedirs components; the first S are used)
    pose:        [B, J * 3] axis-angle (root first) when pose2rot, else [B, J, 3, 3] matrices
    v_template:  [V, 3] rest-pose template, metres
    shapedirs:   [V, 3, S'] shape blend basis, metres per unit beta
    posedirs:    [V, 3, 9 * (J - 1)] pose-corrective basis, metres per unit feature
    J_regressor: [J, V]
    parents:     [J]
    weights:     [V, J] skinning weights
    Returns an :class:`LbsOutput`; vertices and joints equal smplx's ``lbs`` outputs
    (whose posedirs argument is this posedirs reshaped to [V*3, P] and transposed).
    """
    batch = betas.shape[0]
    num_joints = J_regressor.shape[0]
    if betas.shape[1] > shapedirs.shape[2]:
        raise ValueError(f"lbs: {betas.shape[1]} betas for a model with {shapedirs.shape[2]} shape components")
    v_shaped = v_template + blend_shapes(betas, shapedirs[..., : betas.shape[1]])  # [B, V, 3]
    rest_joints = vertices_to_joints(J_regressor, v_shaped)  # [B, J, 3]
    if pose2rot:
        if pose.shape != (batch, num_joints * 3):
            raise ValueError(f"lbs: pose must be [{batch}, {num_joints * 3}], found {tuple(pose.shape)}")
        rot_mats = batch_rodrigues(pose.reshape(batch, num_joints, 3))  # [B, J, 3, 3]
    else:
        if pose.shape != (batch, num_joints, 3, 3):
            raise ValueError(f"lbs: pose must be [{batch}, {num_joints}, 3, 3], found {tuple(pose.shape)}")
        rot_mats = pose
    v_posed = v_shaped + blend_shapes(pose_features(rot_mats), posedirs)  # [B, V, 3]
    posed_joints, transforms = batch_rigid_transform(rot_mats, rest_joints, parents)
    vertices = skin_vertices(weights, transforms, v_posed)
    return LbsOutput(vertices, posed_joints, transforms, v_posed, rest_joints)
