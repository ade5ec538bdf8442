"""EWA projection of 3D Gaussians to the image (paper Eq. 3; gsplat's conventions).

Pure PyTorch, differentiable, shared by every backend: a Gaussian's 3D covariance
Σ goes to the image as J W Σ Wᵀ Jᵀ (W: world-to-camera rotation, J: Jacobian of
the perspective map at the mean, with gsplat's clamp of x/z and y/z to 1.3x the
field of view), plus a 0.3-pixel low-pass dilation on the diagonal (optionally
with Mip-Splatting's opacity compensation, ``antialiased``).

Pixels follow OpenCV (CONTRACTS.md): the centre of pixel (u, v) is at (u, v).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

ALPHA_MIN = 1.0 / 255.0  # a Gaussian contributes to a pixel only where its alpha reaches this
ALPHA_MAX = 0.999  # alphas are clamped here (gsplat)
TRANSMITTANCE_MIN = 1e-4  # a pixel stops compositing before its transmittance would reach this
LOW_PASS = 0.3  # pixels^2 added to the projected covariance's diagonal (3DGS, gsplat eps2d)
FOV_MARGIN = 0.3  # J is built with x/z, y/z clamped to the image plus this fraction of its size per side (gsplat)
RADIUS_SIGMAS = 3.0  # the reported screen radius, in standard deviations (3DGS)
DET_FLOOR = 1e-12  # floor of determinants and their ratios, against division by zero
EXTENT_SAFETY = 1e-3  # relative slack on binning extents so rounding never drops a contributing pixel


@dataclass(frozen=True)
class Camera:
    """A pinhole camera: K [3, 3] (OpenCV pixels), world-to-camera R [3, 3] and t [3]."""

    K: Tensor
    R: Tensor
    t: Tensor
    width: int
    height: int
    near: float = 0.01
    far: float = 1e4

    def __post_init__(self) -> None:
        if self.K.shape != (3, 3) or self.R.shape != (3, 3) or self.t.shape != (3,):
            raise ValueError(f"Camera: need K [3,3], R [3,3], t [3]; found {tuple(self.K.shape)}, "
                             f"{tuple(self.R.shape)}, {tuple(self.t.shape)}")
        if self.width < 1 or self.height < 1 or not 0 < self.near < self.far:
            raise ValueError(f"Camera: need positive size and 0 < near < far, found {self.width}x{self.height}, "
                             f"near {self.near}, far {self.far}")

    @property
    def centre(self) -> Tensor:
        """[3] the camera centre in the world frame: -Rᵀ t."""
        return -self.R.T @ self.t


@dataclass(frozen=True)
class Projected:
    """Gaussians on the image. Entries of culled Gaussians (``visible`` False) are meaningless.

    means2d [N, 2] pixels; conics [N, 3] (a, b, c) of the inverse 2D covariance [[a, b], [b, c]];
    depths [N] camera z (metres); opacities [N] (after antialiasing compensation);
    radii [N] int32 3-sigma screen radius (0 when culled); extents [N, 2] half-width and
    half-height (pixels) of the box outside which alpha < 1/255 (for tile binning);
    visible [N] bool.
    """

    means2d: Tensor
    conics: Tensor
    depths: Tensor
    opacities: Tensor
    radii: Tensor
    extents: Tensor
    visible: Tensor


def quat_to_rotation(quats: Tensor) -> Tensor:
    """quats [N, 4] wxyz (normalised here) -> rotation matrices [N, 3, 3]."""
    w, x, y, z = torch.nn.functional.normalize(quats, dim=-1).unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], dim=-1).reshape(-1, 3, 3)


def quat_scale_to_covariance_torch(quats: Tensor, scales: Tensor) -> Tensor:
    """quats [N, 4] wxyz (normalised here), scales [N, 3] (linear, metres) -> covariances [N, 3, 3] = R S Sᵀ Rᵀ
    (the reference, in PyTorch)."""
    scaled = quat_to_rotation(quats) * scales[:, None, :]
    return scaled @ scaled.transpose(1, 2)


class _CovarianceCPU(torch.autograd.Function):
    """quat_scale_to_covariance_torch computed by the C++ kernel (csrc/preprocess_cpu.cpp), hand-written backward."""

    @staticmethod
    def forward(ctx, quats: Tensor, scales: Tensor) -> Tensor:
        from glimpse.render.composite_cpu import extension

        inputs = [t.detach().contiguous() for t in (quats, scales)]
        ctx.save_for_backward(*inputs)
        return extension().covariance_forward(*inputs)

    @staticmethod
    def backward(ctx, v_covariances: Tensor):
        from glimpse.render.composite_cpu import extension

        return tuple(extension().covariance_backward(*ctx.saved_tensors, v_covariances.float()))


def quat_scale_to_covariance(quats: Tensor, scales: Tensor) -> Tensor:
    """quats [N, 4] wxyz (normalised here), scales [N, 3] (linear, metres) -> covariances [N, 3, 3] = R S Sᵀ Rᵀ;
    by the C++ kernel for float32 CPU tensors where it builds, by gsplat's for float32 CUDA tensors where it
    is installed, else by the PyTorch reference (same maths)."""
    from glimpse.render.composite_cpu import kernel_applies
    from glimpse.render.gsplat_backend import gsplat_ops_apply, quat_scale_to_covariance_gsplat

    if kernel_applies(quats, scales):
        return _CovarianceCPU.apply(quats, scales)
    if quats.ndim == 2 and gsplat_ops_apply(quats, scales):
        return quat_scale_to_covariance_gsplat(quats, scales)
    return quat_scale_to_covariance_torch(quats, scales)


def project_gaussians(means: Tensor, covariances: Tensor, opacities: Tensor, camera: Camera,
                      antialiased: bool = False) -> Projected:
    """Project Gaussians (world frame): means [N, 3], covariances [N, 3, 3], opacities [N] in [0, 1]."""
    K, R, t = camera.K.to(means), camera.R.to(means), camera.t.to(means)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    cam = means @ R.T + t  # [N, 3]
    x, y, z = cam.unbind(-1)
    in_depth = (z > camera.near) & (z < camera.far)
    z_safe = torch.where(in_depth, z, torch.ones_like(z))
    # Jacobian of the perspective map, with x/z and y/z clamped (gsplat) for stability at the borders
    margin_x, margin_y = FOV_MARGIN * camera.width / fx, FOV_MARGIN * camera.height / fy
    tx = z_safe * torch.clamp(x / z_safe, -cx / fx - margin_x, (camera.width - cx) / fx + margin_x)
    ty = z_safe * torch.clamp(y / z_safe, -cy / fy - margin_y, (camera.height - cy) / fy + margin_y)
    zero = torch.zeros_like(z)
    J = torch.stack([fx / z_safe, zero, -fx * tx / z_safe**2, zero, fy / z_safe, -fy * ty / z_safe**2],
                    -1).reshape(-1, 2, 3)
    M = J @ R  # [N, 2, 3]
    cov2d = M @ covariances @ M.transpose(1, 2)  # [N, 2, 2]
    a0, b0, c0 = cov2d[:, 0, 0], cov2d[:, 0, 1], cov2d[:, 1, 1]
    a, c = a0 + LOW_PASS, c0 + LOW_PASS
    det = a * c - b0 * b0
    if antialiased:  # Mip-Splatting: keep each Gaussian's total weight under the dilation
        ratio = (a0 * c0 - b0 * b0) / det.clamp(min=DET_FLOOR)
        opacities = opacities * torch.sqrt(ratio.clamp(min=DET_FLOOR))  # floor: finite gradient when flat
    valid = in_depth & (det > 0)
    det_safe = torch.where(valid, det, torch.ones_like(det))
    conics = torch.stack([c / det_safe, -b0 / det_safe, a / det_safe], dim=-1)
    means2d = torch.stack([fx * x / z_safe + cx, fy * y / z_safe + cy], dim=-1)
    return _finish_projection(means2d, conics, z, opacities, torch.stack([a, b0, c], -1).detach(), valid, camera)


def _finish_projection(means2d: Tensor, conics: Tensor, depths: Tensor, opacities: Tensor, cov2d: Tensor,
                       valid: Tensor, camera: Camera) -> Projected:
    """Screen extents, radii and visibility (no gradients) from the dilated 2D covariances [N, 3] (a, b, c)."""
    with torch.no_grad():
        a, b, c = cov2d.unbind(-1)
        # alpha = o exp(-s) >= 1/255 only where s <= ln(255 o): an ellipse with these half-extents
        level = torch.log(torch.clamp(opacities.detach() / ALPHA_MIN, min=1.0))
        extents = torch.stack([torch.sqrt(2 * level * a), torch.sqrt(2 * level * c)], -1) * (1 + EXTENT_SAFETY)
        mx, my = means2d.detach().unbind(-1)
        on_image = ((mx + extents[:, 0] >= 0) & (mx - extents[:, 0] <= camera.width - 1)
                    & (my + extents[:, 1] >= 0) & (my - extents[:, 1] <= camera.height - 1))
        visible = valid & on_image & (level > 0)
        largest = 0.5 * (a + c) + torch.sqrt(torch.clamp(0.25 * (a - c) ** 2 + b * b, min=0.0))
        radii = torch.where(visible, torch.ceil(RADIUS_SIGMAS * torch.sqrt(largest)), torch.zeros_like(a))
        extents = torch.where(visible[:, None], extents, torch.zeros_like(extents))
    return Projected(means2d=means2d, conics=conics, depths=depths, opacities=opacities,
                     radii=radii.to(torch.int32), extents=extents, visible=visible)


class _ProjectCPU(torch.autograd.Function):
    """The C++ projection (csrc/project_cpu.cpp) with its hand-written backward."""

    @staticmethod
    def forward(ctx, means: Tensor, covariances: Tensor, opacities: Tensor, camera: Camera, antialiased: bool):
        from glimpse.render.composite_cpu import extension

        inputs = [t.detach().float().contiguous() for t in (means, covariances, opacities)]
        geometry = (camera.K.cpu(), camera.R.cpu(), camera.t.cpu(), camera.width, camera.height, camera.near,
                    camera.far, antialiased)
        means2d, conics, depths, opacities_out, cam, extents, radii, visible = extension().project_forward(
            *inputs, *geometry)
        ctx.save_for_backward(*inputs, cam)
        ctx.geometry = geometry
        ctx.mark_non_differentiable(extents, radii, visible)
        ctx.set_materialize_grads(False)  # no zero gradients built for the screen boxes; the others filled below
        return means2d, conics, depths, opacities_out, extents, radii, visible

    @staticmethod
    def backward(ctx, v_means2d, v_conics, v_depths, v_opacities, _v_extents, _v_radii, _v_visible):
        from glimpse.render.composite_cpu import extension

        means, covariances, opacities, cam = ctx.saved_tensors
        n = len(means)
        cotangents = [means.new_zeros(shape) if v is None else v.float()
                      for v, shape in ((v_means2d, (n, 2)), (v_conics, (n, 3)), (v_depths, (n,)), (v_opacities, (n,)))]
        grads = extension().project_backward(means, covariances, opacities, cam, *ctx.geometry, *cotangents)
        return (*grads, None, None)


def project_gaussians_cpu(means: Tensor, covariances: Tensor, opacities: Tensor, camera: Camera,
                          antialiased: bool = False) -> Projected:
    """project_gaussians computed by the C++ kernel (float32), screen boxes included; same outputs and gradients."""
    means2d, conics, depths, opacities_out, extents, radii, visible = _ProjectCPU.apply(
        means, covariances, opacities, camera, antialiased)
    return Projected(means2d=means2d, conics=conics, depths=depths, opacities=opacities_out, radii=radii,
                     extents=extents, visible=visible)


def fov_to_focal(fov_deg: float, pixels: int) -> float:
    """Focal length in pixels for a field of view across ``pixels``."""
    return 0.5 * pixels / math.tan(math.radians(fov_deg) / 2.0)
