"""After training: which Gaussians the input frames ever showed, the background alone from each
input view, its PSNR on background pixels, and the pixels whose background was never seen.

A Gaussian's *seen weight* is the sum, over every input frame's background pixels, of its
blending weight there (the gradient of the masked sum of a colour channel with respect to
its colour). Below ``never_seen_min_weight`` it is *never seen*: every frame shows it only
behind people, so its colour is a guess (the init's).

A *pixel* of an input view is never seen when the background surface rendered there (the
point at the rendered depth) falls on a person, or outside the image, in every input frame;
or when the background covers less than half of it. Frames that share one camera are tested
together (for a static camera this is the pixels people cover in every frame).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from glimpse.background.train import TrainingView
from glimpse.gaussians.model import GaussianModel
from glimpse.metrics.image import psnr
from glimpse.render import Camera, rasterize
from glimpse.render.config import RenderConfig

SEEN_COVERAGE = 0.5  # a pixel whose background alpha is below this counts as never seen


def seen_weights(model: GaussianModel, views: list[TrainingView], render: RenderConfig) -> Tensor:
    """[N] summed blending weight of each Gaussian over the background pixels of ``views``."""
    inputs = {k: v.detach() for k, v in model.render_inputs().items() if k not in ("sh", "sh_degree")}
    total = torch.zeros(len(model), device=model.means.device)
    for view in views:
        probe = torch.zeros(len(model), 3, device=model.means.device, requires_grad=True)
        out = rasterize(view.camera, **inputs, colors=probe, settings=render)
        (out.rgb[..., 0] * view.background).sum().backward()
        total += probe.grad[:, 0]
    return total


@dataclass
class ViewResult:
    """One input view: the background render [H, W, 3] uint8 (black where nothing covers), its PSNR (dB)
    against the frame on background pixels, and never_seen [H, W] bool."""

    frame_id: int
    render: np.ndarray
    psnr_background_db: float
    never_seen: np.ndarray


class SeenTest:
    """Whether world points are shown on a background pixel by some input view; views sharing one
    camera are merged (their background masks or-ed). Masks are kept as bits (a moving camera keeps one
    per frame: 1/8 of a bool mask, and the frames themselves are not held)."""

    def __init__(self, views: list[TrainingView]):
        self.cameras: list[Camera] = []
        self.backgrounds: list[Tensor] = []  # per camera, [ceil(H * W / 8)] packed bits (pack_bits)
        for view in views:
            packed = pack_bits(view.background.reshape(-1))
            same = next((k for k, camera in enumerate(self.cameras) if _same_camera(camera, view.camera)), None)
            if same is not None:
                self.backgrounds[same] = self.backgrounds[same] | packed  # or-ing bytes ors their pixels
            else:
                self.cameras.append(view.camera)
                self.backgrounds.append(packed)

    def seen(self, points: Tensor) -> Tensor:
        """points [P, 3] world -> [P] bool."""
        seen = torch.zeros(len(points), dtype=torch.bool, device=points.device)
        for camera, background in zip(self.cameras, self.backgrounds):
            cam = points @ camera.R.T + camera.t
            z = cam[:, 2]
            uv = cam[:, :2] / z.clamp(min=camera.near)[:, None] * torch.stack([camera.K[0, 0], camera.K[1, 1]]) \
                + camera.K[:2, 2]
            u, v = uv.round().long().unbind(-1)
            inside = (z > camera.near) & (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)
            seen[inside] |= bit_at(background, v[inside] * camera.width + u[inside])
        return seen


def pack_bits(mask: Tensor) -> Tensor:
    """[N] bool -> [ceil(N / 8)] uint8, eight pixels a byte, the first in the highest bit."""
    padded = torch.zeros((mask.numel() + 7) // 8 * 8, dtype=torch.uint8, device=mask.device)
    padded[:mask.numel()] = mask.to(torch.uint8)
    weights = torch.tensor([128, 64, 32, 16, 8, 4, 2, 1], dtype=torch.uint8, device=mask.device)
    return (padded.reshape(-1, 8) * weights).sum(1, dtype=torch.uint8)


def bit_at(packed: Tensor, index: Tensor) -> Tensor:
    """Pixels ``index`` [P] long of a packed mask -> [P] bool."""
    return ((packed[index >> 3] >> (7 - (index & 7)).to(torch.uint8)) & 1).bool()


def _same_camera(a: Camera, b: Camera) -> bool:
    return (a.width, a.height) == (b.width, b.height) and all(
        torch.equal(x, y) for x, y in ((a.K, b.K), (a.R, b.R), (a.t, b.t)))


def backproject(camera: Camera, depth: Tensor) -> Tensor:
    """depth [H, W] (camera z) -> world points [H*W, 3] at each pixel centre."""
    v, u = torch.meshgrid(torch.arange(camera.height, device=depth.device, dtype=depth.dtype),
                          torch.arange(camera.width, device=depth.device, dtype=depth.dtype), indexing="ij")
    x = (u - camera.K[0, 2]) / camera.K[0, 0] * depth
    y = (v - camera.K[1, 2]) / camera.K[1, 1] * depth
    cam = torch.stack([x, y, depth], -1).reshape(-1, 3)
    return (cam - camera.t) @ camera.R


def render_views(model: GaussianModel, views: list[TrainingView], render: RenderConfig):
    """Yield a :class:`ViewResult` per view (one at a time: a long video needs no memory for all)."""
    test = SeenTest(views)
    with torch.no_grad():
        for view in views:
            out = rasterize(view.camera, **model.render_inputs(), settings=render)
            rgb = out.rgb.clamp(0.0, 1.0)
            value = psnr(rgb, view.target(), view.background) if bool(view.background.any()) else torch.tensor(float("nan"))
            seen = test.seen(backproject(view.camera, out.depth)).reshape(out.alpha.shape)
            never_seen = ~seen | (out.alpha < SEEN_COVERAGE)
            yield ViewResult(view.frame_id, (rgb * 255.0).round().byte().cpu().numpy(), float(value),
                             never_seen.cpu().numpy())
