"""The body's joints and detector keypoints without posing its vertices: what a keypoint fit
evaluates hundreds of times per frame.

A keypoint is ``joint_weights @ posed_joints + sum_m w_m * posed_vertex_m`` (glimpse.body.keypoints).
Linear blend skinning is linear in the rest vertex, so a landmark's vertex part is exactly

    sum_j  T_j[:3, :3] @ P_kj  +  a_kj * T_j[:3, 3],    P_kj = sum_m w_m W_mj * rest_vertex_m,
                                                        a_kj = sum_m w_m W_mj,

and ``rest_vertex_m`` is linear in betas and in the pose-corrective features. The weighted
sums over each landmark's vertices (anny's ear landmarks use 4,097) are folded into small
per-(keypoint, joint) bases once, here; the result equals BodyModel + KeypointMap to rounding.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from glimpse.body.keypoints import KeypointMap
from glimpse.body.lbs import batch_rigid_transform, batch_rodrigues, pose_features
from glimpse.body.model import BodyModel


class KeypointBodyOutput(NamedTuple):
    joints: Tensor  # [B, 24, 3] posed joints, world units
    keypoints: Tensor  # [B, K, 3] the layout's keypoints, world units


class KeypointBody(torch.nn.Module):
    """``scale * posed + transl`` of the 24 joints and one layout's keypoints (BodyModel's convention)."""

    def __init__(self, model: BodyModel, kmap: KeypointMap):
        super().__init__()
        self.layout = kmap.layout
        self.names = kmap.names
        self._parents = tuple(int(p) for p in model.parents.tolist())
        dtype = model.dtype
        shapedirs = model.shapedirs  # [V, 3, S]
        self.register_buffer("joint_template", model.J_regressor @ model.v_template)  # [24, 3]
        self.register_buffer("joint_shapedirs", torch.einsum("jv,vcs->jcs", model.J_regressor, shapedirs))
        self.register_buffer("joint_weights", torch.as_tensor(kmap.joint_weights, dtype=dtype))  # [K, 24]
        idx = torch.as_tensor(kmap.vertex_indices)  # [K, M]
        w = torch.as_tensor(kmap.vertex_weights, dtype=dtype)  # [K, M]
        skin = w[..., None] * model.weights[idx]  # [K, M, 24]: w_m * W_mj
        self.register_buffer("landmark_joint_mass", skin.sum(1))  # [K, 24] a_kj
        self.register_buffer("landmark_template", torch.einsum("kmj,kmc->kjc", skin, model.v_template[idx]))
        self.register_buffer("landmark_shapedirs", torch.einsum("kmj,kmcs->kjcs", skin, shapedirs[idx]))
        self.register_buffer("landmark_posedirs", torch.einsum("kmj,kmcp->kjcp", skin, model.posedirs[idx]))

    def rest_joints(self, betas: Tensor) -> Tensor:
        """betas [10] or [B, 10] -> the shaped body's 24 rest joints [24, 3] or [B, 24, 3], metres."""
        return self.joint_template + torch.einsum("jcs,...s->...jc", self.joint_shapedirs, betas)

    def size_ratio(self, betas: Tensor) -> Tensor:
        """[] the shaped body's size over the template's: the RMS distance of the 24 rest joints from their
        centroid, for betas [10]. Differentiable; 1 at betas = 0."""
        def spread(joints: Tensor) -> Tensor:
            return (joints - joints.mean(0)).square().sum(-1).mean().sqrt()

        return spread(self.rest_joints(betas)) / spread(self.joint_template)

    def forward(self, betas: Tensor, global_orient: Tensor, body_pose: Tensor, transl: Tensor,
                scale: Tensor) -> KeypointBodyOutput:
        """betas [10] (shared) or [B, 10]; global_orient [B, 3]; body_pose [B, 69]; transl [B, 3]; scale [] or [B]."""
        batch = global_orient.shape[0]
        betas_b = betas.expand(batch, -1) if betas.ndim == 1 else betas
        rest_joints = self.rest_joints(betas_b)
        rotations = batch_rodrigues(torch.cat([global_orient, body_pose], 1).reshape(batch, -1, 3))
        joints, transforms = batch_rigid_transform(rotations, rest_joints, self._parents)
        features = pose_features(rotations)  # [B, 207]
        rest_points = (self.landmark_template
                       + torch.einsum("kjcs,bs->bkjc", self.landmark_shapedirs, betas_b)
                       + torch.einsum("kjcp,bp->bkjc", self.landmark_posedirs, features))  # [B, K, 24, 3]
        from_vertices = (torch.einsum("bjcd,bkjd->bkc", transforms[..., :3, :3], rest_points)
                         + torch.einsum("kj,bjc->bkc", self.landmark_joint_mass, transforms[..., :3, 3]))
        keypoints = torch.einsum("kj,bjc->bkc", self.joint_weights, joints) + from_vertices
        s = scale.reshape(-1, 1, 1) if scale.ndim else scale
        t = transl[:, None, :]
        return KeypointBodyOutput(s * joints + t, s * keypoints + t)
