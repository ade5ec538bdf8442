"""The SMPL body model as a batched, differentiable torch module.

Convention (the project's contract): for each body b

    posed = scale[b] * LBS(betas[b], global_orient[b], body_pose[b]) + transl[b]

where LBS is exactly smplx's SMPL output with ``transl = 0`` (the body posed about its
own origin: the root joint stays at its shaped rest location). Units: metres, radians.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from glimpse.body.lbs import lbs
from glimpse.body.model_file import NUM_BODY_JOINTS, NUM_JOINTS, BodyModelData, load_body_model_file

AXIS_ANGLE_DIM = 3
BODY_POSE_DIM = NUM_BODY_JOINTS * AXIS_ANGLE_DIM  # 69
DEFAULT_NUM_BETAS = 10
SUPPORTED_DTYPES = (torch.float32, torch.float64)

TensorLike = Tensor | np.ndarray | float | list[Any]


@dataclass(frozen=True)
class BodyOutput:
    """Result of :meth:`BodyModel.forward` (B bodies, V vertices)."""

    vertices: Tensor  # [B, V, 3] posed, world frame, metres
    joints: Tensor  # [B, 24, 3] posed joints, world frame, metres
    # [B, 24, 4, 4] per-joint skinning transforms including scale and transl:
    #   vertices = sum_j weights[v, j] * transforms[:, j] @ [rest_vertex; 1]
    # (rest_vertex = rest_vertices[:, v]; holds because skinning weight rows sum to 1)
    transforms: Tensor
    rest_vertices: Tensor  # [B, V, 3] template + shape blend + pose blend, before skinning (model frame)
    rest_joints: Tensor  # [B, 24, 3] joints of the shaped rest pose (model frame)


class BodyModel(torch.nn.Module):
    """SMPL (or the project's SMPL-layout "free" model) with scale and translation.

    The model arrays are buffers (moved by ``.to()``, never trained). Every output is
    differentiable w.r.t. betas, global_orient, body_pose, transl and scale.
    """

    v_template: Tensor  # [V, 3]
    shapedirs: Tensor  # [V, 3, num_betas]
    posedirs: Tensor  # [V, 3, 207]
    J_regressor: Tensor  # [24, V]
    weights: Tensor  # [V, 24]
    parents: Tensor  # [24] long
    faces: Tensor  # [F, 3] long

    def __init__(self, data: BodyModelData, num_betas: int = DEFAULT_NUM_BETAS, dtype: torch.dtype = torch.float32):
        super().__init__()
        if dtype not in SUPPORTED_DTYPES:
            raise ValueError(f"BodyModel: dtype must be torch.float32 or torch.float64, found {dtype}")
        if not 1 <= num_betas <= data.num_shape_components:
            raise ValueError(
                f"BodyModel: num_betas must be in [1, {data.num_shape_components}] for {data.source}, found {num_betas}"
            )
        self.data = data
        self.kind = data.kind
        self.num_vertices = data.num_vertices
        self.num_betas = num_betas
        self._parent_list = tuple(int(p) for p in data.parents)

        def floats(array: np.ndarray) -> Tensor:
            return torch.tensor(np.ascontiguousarray(array), dtype=dtype)

        self.register_buffer("v_template", floats(data.v_template))
        self.register_buffer("shapedirs", floats(data.shapedirs[:, :, :num_betas]))
        self.register_buffer("posedirs", floats(data.posedirs))
        self.register_buffer("J_regressor", floats(data.J_regressor))
        self.register_buffer("weights", floats(data.weights))
        self.register_buffer("parents", torch.tensor(data.parents, dtype=torch.long))
        self.register_buffer("faces", torch.tensor(data.faces, dtype=torch.long))

    @classmethod
    def from_file(cls, path: str | Path, **kwargs: Any) -> BodyModel:
        """Load an SMPL-format .pkl / .npz (see glimpse.body.model_file) and build the model."""
        return cls(load_body_model_file(path), **kwargs)

    @property
    def dtype(self) -> torch.dtype:
        return self.v_template.dtype

    @property
    def device(self) -> torch.device:
        return self.v_template.device

    def extra_repr(self) -> str:
        return f"kind={self.kind}, vertices={self.num_vertices}, num_betas={self.num_betas}, dtype={self.dtype}"

    def forward(
        self,
        betas: TensorLike,
        global_orient: TensorLike,
        body_pose: TensorLike,
        transl: TensorLike | None = None,
        scale: TensorLike | None = None,
    ) -> BodyOutput:
        """Pose B bodies.

        betas:         [B, num_betas] or [num_betas] (shared by all bodies)
        global_orient: [B, 3] axis-angle of the root (pelvis), radians
        body_pose:     [B, 69] (or [B, 23, 3]) axis-angle of joints 1..23 relative to their parents
        transl:        [B, 3] or [3] metres, default 0
        scale:         [B] or a scalar, default 1
        Inputs are cast to the model's dtype and device (differentiably).
        """
        global_orient = self._as_tensor(global_orient)
        body_pose = self._as_tensor(body_pose)
        if global_orient.ndim != 2 or global_orient.shape[1] != AXIS_ANGLE_DIM:
            raise ValueError(f"BodyModel: global_orient must be [B, 3], found {tuple(global_orient.shape)}")
        batch = global_orient.shape[0]
        if body_pose.shape == (batch, NUM_BODY_JOINTS, AXIS_ANGLE_DIM):
            body_pose = body_pose.reshape(batch, BODY_POSE_DIM)
        if body_pose.shape != (batch, BODY_POSE_DIM):
            raise ValueError(
                f"BodyModel: body_pose must be [{batch}, {BODY_POSE_DIM}] to match global_orient, "
                f"found {tuple(body_pose.shape)}"
            )
        betas_b = self._per_body(betas, batch, (self.num_betas,), "betas")
        transl_b = (
            torch.zeros(batch, 3, dtype=self.dtype, device=self.device)
            if transl is None
            else self._per_body(transl, batch, (3,), "transl")
        )
        scale_b = (
            torch.ones(batch, dtype=self.dtype, device=self.device)
            if scale is None
            else self._per_body(scale, batch, (), "scale")
        )

        pose = torch.cat([global_orient, body_pose], dim=1)  # [B, 72]
        out = lbs(
            betas_b,
            pose,
            self.v_template,
            self.shapedirs,
            self.posedirs,
            self.J_regressor,
            self._parent_list,
            self.weights,
        )
        s = scale_b[:, None, None]  # [B, 1, 1]
        t = transl_b[:, None, :]  # [B, 1, 3]
        return BodyOutput(
            vertices=s * out.vertices + t,
            joints=s * out.joints + t,
            transforms=scaled_translated(out.transforms, scale_b, transl_b),
            rest_vertices=out.rest_vertices,
            rest_joints=out.rest_joints,
        )

    def stature(self, betas: TensorLike) -> Tensor:
        """[] standing height of the shape ``betas`` [num_betas]: the rest pose's extent along the model's up
        (y), from the soles to the top of the head, in metres before any scale."""
        zero = torch.zeros(1, AXIS_ANGLE_DIM, dtype=self.dtype, device=self.device)
        up = self(betas, zero, zero.new_zeros(1, BODY_POSE_DIM)).rest_vertices[0, :, 1]
        return up.max() - up.min()

    # ------------------------------------------------------------------ input handling

    def _as_tensor(self, value: TensorLike) -> Tensor:
        if isinstance(value, Tensor):
            return value.to(device=self.device, dtype=self.dtype)
        return torch.as_tensor(np.asarray(value), dtype=self.dtype, device=self.device)

    def _per_body(self, value: TensorLike, batch: int, item_shape: tuple[int, ...], name: str) -> Tensor:
        """[B, *item_shape], or one [*item_shape] / [1, *item_shape] broadcast to B -> [B, *item_shape]."""
        tensor = self._as_tensor(value)
        if tensor.shape == item_shape or tensor.shape == (1, *item_shape):
            return tensor.reshape(item_shape).expand(batch, *item_shape)
        if tensor.shape == (batch, *item_shape):
            return tensor
        want = ", ".join(str(n) for n in (batch, *item_shape))
        one = f"[{', '.join(str(n) for n in item_shape)}]" if item_shape else "a scalar"
        raise ValueError(f"BodyModel: {name} must be [{want}] or {one}, found {tuple(tensor.shape)}")


def scaled_translated(transforms: Tensor, scale: Tensor, transl: Tensor) -> Tensor:
    """[[s I, t], [0, 1]] @ transforms: [B, J, 4, 4], scale [B], transl [B, 3] -> [B, J, 4, 4]."""
    top = scale[:, None, None, None] * transforms[..., :3, :]  # [B, J, 3, 4]
    translation = top[..., 3] + transl[:, None, :]  # [B, J, 3]
    top = torch.cat([top[..., :3], translation[..., None]], dim=-1)
    return torch.cat([top, transforms[..., 3:, :]], dim=-2)


__all__ = ["BodyModel", "BodyOutput", "NUM_JOINTS"]
