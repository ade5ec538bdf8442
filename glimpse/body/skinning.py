"""Skinning for Gaussians in a person's canonical body space (paper Sec. 4.3, Eq. 6-8).

- Skin weights at any canonical point: inverse-distance weighting of the k
  nearest canonical body vertices' weights (paper: k = 30; official code: k = 1),
  baked into a voxel grid around the body (with a margin, which the official
  code lacks) and looked up trilinearly.
- Deformation: a canonical point goes back to the rest pose by the inverse of its
  blended canonical transform, then forward by its blended posed transform:
  A = (sum_j w_j P_j) (sum_j w_j C_j)^-1, with P_j, C_j the joints' skinning
  transforms in the target and the canonical pose. Means move by A, covariances
  become A Σ Aᵀ with A's 3x3 part (not re-orthonormalised, so it includes the
  person's scale). A point on a body vertex then moves exactly as that vertex.
  GTU blends relative transforms instead, A = sum_j w_j P_j C_j^-1 (paper Eq. 6);
  both agree where the canonical pose equals the rest pose, and differ around the
  hips of the Da-pose, where GTU's moves body vertices off the posed body.
- The canonical pose is GTU's "Da-pose": zero pose but the hips rotated by
  +-30 degrees about z, legs spread.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import torch
import torch.nn.functional as F
from scipy.sparse import csr_matrix
from scipy.spatial import cKDTree
from torch import Tensor

from glimpse.body.model_file import NUM_BODY_JOINTS

LEFT_HIP_Z, RIGHT_HIP_Z = 2, 5  # indices of the hips' z rotation in the 69-value body_pose
SKINNING_FORMAT = "glimpse-skinning/1"
_DISTANCE_FLOOR = 1e-9  # metres: a point on a vertex takes that vertex's weights


def canonical_body_pose(hip_angle_deg: float) -> np.ndarray:
    """(69,) the Da-pose: zeros except the left/right hip rotated +-angle about z (legs apart)."""
    pose = np.zeros(NUM_BODY_JOINTS * 3)
    pose[LEFT_HIP_Z] = math.radians(hip_angle_deg)
    pose[RIGHT_HIP_Z] = -math.radians(hip_angle_deg)
    return pose


def idw_skin_weights(points: np.ndarray, vertices: np.ndarray, vertex_weights: np.ndarray, k: int,
                     power: float) -> np.ndarray:
    """Skin weights at ``points`` (N, 3) from the k nearest of ``vertices`` (V, 3).

    vertex_weights: (V, J). Each neighbour counts 1 / distance**power; rows sum to 1. A point
    on a vertex gets exactly that vertex's weights. Returns (N, J).
    """
    if k < 1:
        raise ValueError(f"skinning k must be >= 1, found {k}")
    distances, nearest = cKDTree(vertices).query(points, k=k, workers=-1)
    distances, nearest = distances.reshape(len(points), k), nearest.reshape(len(points), k)
    on_vertex = distances[:, 0] < _DISTANCE_FLOOR
    inverse = 1.0 / np.maximum(distances, _DISTANCE_FLOOR) ** power  # [N, k]
    inverse[on_vertex] = 0.0
    inverse[on_vertex, 0] = 1.0
    inverse /= inverse.sum(1, keepdims=True)
    # One sparse [N, V] matrix of the neighbours' shares times the [V, J] weights: the same sums as gathering
    # [N, k, J] neighbour weights, without the gathered copy (1.5 GB for a 64^3 grid at k = 30)
    shares = csr_matrix((inverse.ravel(), nearest.ravel(), np.arange(0, len(points) * k + 1, k)),
                        shape=(len(points), len(vertices)))
    return np.asarray(shares @ vertex_weights)


@dataclass(frozen=True)
class SkinWeightGrid:
    """Skin weights sampled on a cube of resolution^3 voxel corners (canonical frame, metres).

    weights: [J, R, R, R] indexed (joint, z, y, x); bounds_min/bounds_max: [3] the cube's corners.
    """

    weights: Tensor
    bounds_min: Tensor
    bounds_max: Tensor

    @property
    def resolution(self) -> int:
        return int(self.weights.shape[-1])

    @cached_property
    def joints_last(self) -> Tensor:
        """[R, R, R, J] the weights with the joints last and contiguous (the C++ posing kernel's layout), made
        once."""
        return self.weights.permute(1, 2, 3, 0).float().contiguous()

    def lookup(self, points: Tensor) -> Tensor:
        """points [N, 3] -> skin weights [N, J] by trilinear interpolation; points outside the cube
        take the weights of the nearest face of the cube (callers prune them: see ``inside``)."""
        unit = (points - self.bounds_min) / (self.bounds_max - self.bounds_min) * 2.0 - 1.0  # [-1, 1]
        grid = unit.to(self.weights.dtype).view(1, -1, 1, 1, 3)  # grid_sample wants (x, y, z)
        sampled = F.grid_sample(self.weights[None], grid, mode="bilinear", padding_mode="border", align_corners=True)
        return sampled.view(self.weights.shape[0], -1).T

    def inside(self, points: Tensor) -> Tensor:
        """[N] bool: points within the cube."""
        return ((points >= self.bounds_min) & (points <= self.bounds_max)).all(dim=-1)

    def to_npz_dict(self) -> dict[str, np.ndarray]:
        return {"format": np.array(SKINNING_FORMAT), "weights": self.weights.cpu().numpy(),
                "bounds_min": self.bounds_min.cpu().numpy(), "bounds_max": self.bounds_max.cpu().numpy()}

    @classmethod
    def from_npz_dict(cls, data, source: str = "skinning.npz") -> "SkinWeightGrid":
        from glimpse.errors import GlimpseError

        if str(data.get("format", "")) != SKINNING_FORMAT:
            raise GlimpseError(f"{source}: unknown format {data.get('format')!r}; this reader knows {SKINNING_FORMAT}")
        return cls(torch.as_tensor(data["weights"]), torch.as_tensor(data["bounds_min"]),
                   torch.as_tensor(data["bounds_max"]))


def bake_skin_weight_grid(vertices: np.ndarray, vertex_weights: np.ndarray, resolution: int, margin: float,
                          k: int, power: float, dtype: torch.dtype = torch.float32) -> SkinWeightGrid:
    """Bake IDW skin weights of the canonical body ``vertices`` (V, 3) into a cube.

    The cube is centred on the body's bounding box, with half-side = half its largest
    extent + ``margin`` (metres), so loose clothing and hair around the body stay inside.
    """
    if resolution < 2:
        raise ValueError(f"skin weight grid resolution must be >= 2, found {resolution}")
    lo, hi = vertices.min(0), vertices.max(0)
    centre, half = (lo + hi) / 2.0, (hi - lo).max() / 2.0 + margin
    axis = np.linspace(-half, half, resolution)
    z, y, x = np.meshgrid(axis + centre[2], axis + centre[1], axis + centre[0], indexing="ij")
    corners = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    weights = idw_skin_weights(corners, vertices, vertex_weights, k, power)  # [R^3, J]
    grid = np.ascontiguousarray(weights.T.reshape(-1, resolution, resolution, resolution))  # [J, z, y, x] in memory
    return SkinWeightGrid(torch.as_tensor(grid, dtype=dtype), torch.as_tensor(centre - half, dtype=dtype),
                          torch.as_tensor(centre + half, dtype=dtype))


def blend_transforms(weights: Tensor, transforms: Tensor) -> Tensor:
    """weights [N, J], transforms [J, 4, 4] -> blended transforms [N, 4, 4] (sum_j w_j T_j)."""
    return torch.einsum("nj,jab->nab", weights, transforms)


def invert_affine(transforms: Tensor) -> Tensor:
    """[N, 4, 4] affine transforms (last row 0 0 0 1) -> their inverses [N, 4, 4]."""
    linear_inverse = torch.linalg.inv(transforms[:, :3, :3])
    inverse = torch.zeros_like(transforms)
    inverse[:, :3, :3] = linear_inverse
    inverse[:, :3, 3] = -(linear_inverse @ transforms[:, :3, 3:])[:, :, 0]
    inverse[:, 3, 3] = 1.0
    return inverse


def canonical_to_posed(weights: Tensor, posed_transforms: Tensor, canonical_transforms: Tensor) -> Tensor:
    """Per-point transforms from the canonical body to a target pose.

    weights [N, J]: skin weights of the points; posed_transforms, canonical_transforms [J, 4, 4]:
    BodyOutput.transforms of the same body in the target and the canonical pose.
    Returns [N, 4, 4] = (sum_j w_j P_j) (sum_j w_j C_j)^-1.
    """
    return blend_transforms(weights, posed_transforms) @ invert_affine(blend_transforms(weights, canonical_transforms))


def deform_gaussians(means: Tensor, covariances: Tensor, blended: Tensor) -> tuple[Tensor, Tensor]:
    """Move canonical Gaussians by their blended transforms (paper Eq. 6-7).

    means [N, 3], covariances [N, 3, 3], blended [N, 4, 4]
    Returns posed means [N, 3] and covariances [N, 3, 3] = A Σ Aᵀ (A = blended[:, :3, :3]).
    """
    linear = blended[:, :3, :3]
    posed_means = (linear @ means[:, :, None])[:, :, 0] + blended[:, :3, 3]
    posed_covariances = linear @ covariances @ linear.transpose(1, 2)
    return posed_means, posed_covariances
