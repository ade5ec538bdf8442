"""Trainable Gaussians: the raw 3DGS parameters as ``torch.nn.Parameter`` s.

One parameter per optimiser group (3DGS's layout), so learning rates, densification and
checkpoints address them by name (:data:`PARAMETER_NAMES`):

    means [N, 3]           world units (metres in a metric frame)
    sh_dc [N, 1, 3]        DC spherical-harmonics coefficient (colour = C0 * sh_dc + 0.5)
    sh_rest [N, K-1, 3]    higher-order coefficients, K = (sh_degree + 1)^2
    opacity_logits [N]     opacity = sigmoid(logit)
    log_scales [N, 3]      standard deviations = exp(log_scale), world units
    quats [N, 4]           rotation w, x, y, z (normalised when rendered)
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor, nn

from glimpse.gaussians.ply import GaussianSplats
from glimpse.render.sh import num_sh_coeffs, rgb_to_sh_dc

PARAMETER_NAMES = ("means", "sh_dc", "sh_rest", "opacity_logits", "log_scales", "quats")


def logit(p: float) -> float:
    return math.log(p / (1.0 - p))


class GaussianModel(nn.Module):
    """N Gaussians with SH colours of degree ``sh_degree`` (the degree rendered can be lower)."""

    def __init__(self, means: Tensor, sh_dc: Tensor, sh_rest: Tensor, opacity_logits: Tensor, log_scales: Tensor,
                 quats: Tensor):
        super().__init__()
        n = means.shape[0]
        shapes = {"means": (n, 3), "sh_dc": (n, 1, 3), "opacity_logits": (n,), "log_scales": (n, 3), "quats": (n, 4)}
        for name, tensor in zip(PARAMETER_NAMES, (means, sh_dc, sh_rest, opacity_logits, log_scales, quats)):
            if name in shapes and tuple(tensor.shape) != shapes[name]:
                raise ValueError(f"GaussianModel.{name} must be {shapes[name]}, found {tuple(tensor.shape)}")
            setattr(self, name, nn.Parameter(tensor.detach().clone().float().contiguous()))
        if self.sh_rest.shape[0] != n or self.sh_rest.shape[2] != 3 or self.sh_rest.shape[1] + 1 not in (1, 4, 9, 16):
            raise ValueError(f"GaussianModel.sh_rest must be [N, K-1, 3], found {tuple(self.sh_rest.shape)}")

    @classmethod
    def from_points(cls, points: Tensor, rgb: Tensor, scales: Tensor, opacity: float, sh_degree: int) -> GaussianModel:
        """Isotropic Gaussians at ``points [N, 3]`` with colours ``rgb [N, 3]`` in [0, 1], standard deviations
        ``scales [N]`` (world units), one opacity, identity rotations and zero higher-order SH."""
        n = points.shape[0]
        return cls(points, rgb_to_sh_dc(rgb.float())[:, None, :], torch.zeros(n, num_sh_coeffs(sh_degree) - 1, 3),
                   torch.full((n,), logit(opacity)), torch.log(scales.float())[:, None].expand(n, 3),
                   torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(n, 4))

    @classmethod
    def from_splats(cls, splats: GaussianSplats) -> GaussianModel:
        sh = torch.as_tensor(splats.sh)
        return cls(torch.as_tensor(splats.means), sh[:, :1], sh[:, 1:], torch.as_tensor(splats.opacity_logits),
                   torch.as_tensor(splats.log_scales), torch.as_tensor(splats.quats))

    def to_splats(self) -> GaussianSplats:
        return GaussianSplats.from_tensors(self.means, self.sh(), self.opacity_logits, self.log_scales, self.quats)

    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def sh_degree(self) -> int:
        return int(round(math.sqrt(self.sh_rest.shape[1] + 1))) - 1

    def sh(self) -> Tensor:
        """[N, K, 3] all SH coefficients."""
        return torch.cat([self.sh_dc, self.sh_rest], dim=1)

    def opacities(self) -> Tensor:
        return torch.sigmoid(self.opacity_logits)

    def scales(self) -> Tensor:
        return torch.exp(self.log_scales)

    def render_inputs(self, sh_degree: int | None = None) -> dict[str, Tensor | int]:
        """Keyword arguments of :func:`glimpse.render.rasterize` (colours up to ``sh_degree``)."""
        degree = self.sh_degree if sh_degree is None else min(sh_degree, self.sh_degree)
        return {"means": self.means, "opacities": self.opacities(), "quats": self.quats, "scales": self.scales(),
                "sh": self.sh()[:, : num_sh_coeffs(degree)], "sh_degree": degree}

    def parameter_dict(self) -> dict[str, nn.Parameter]:
        return {name: getattr(self, name) for name in PARAMETER_NAMES}

    def replace_parameters(self, tensors: dict[str, Tensor]) -> None:
        """Swap in new parameter tensors (densification changes N); every name must be given."""
        for name in PARAMETER_NAMES:
            setattr(self, name, tensors[name] if isinstance(tensors[name], nn.Parameter) else nn.Parameter(tensors[name]))


def knn_scales(points: np.ndarray, neighbours: int, floor: float) -> np.ndarray:
    """[N] 3DGS's initial scale: the root mean square distance to each point's ``neighbours`` nearest
    other points (``floor`` where points coincide)."""
    from scipy.spatial import cKDTree

    k = min(neighbours, len(points) - 1)
    if k < 1:
        return np.full(len(points), floor)
    distances, _ = cKDTree(points).query(points, k=k + 1)
    return np.maximum(np.sqrt((distances[:, 1:] ** 2).mean(1)), floor)
