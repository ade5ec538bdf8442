"""Adaptive density control of 3D Gaussian Splatting (Kerbl et al. 2023, Sec. 5.2).

Every few iterations, Gaussians whose mean screen-space gradient is large are densified:
small ones (largest scale <= percent_dense * extent) are cloned, large ones split in
``SPLIT_COUNT`` smaller ones sampled from themselves. Transparent ones are pruned, and,
after the first opacity reset, those too large on screen or in the world. Every so often
opacities are reset low so that Gaussians that are not needed fade and get pruned.

Screen-space gradients are measured as 3DGS measures them: with respect to normalised
device coordinates, i.e. the pixel gradient times (width/2, height/2), so the paper's
threshold (2e-4) keeps its meaning at any resolution.

The optimiser's Adam moments follow the Gaussians: kept ones keep theirs, new ones start
at zero (3DGS's ``densification_postfix``).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn

from glimpse.gaussians.model import PARAMETER_NAMES, GaussianModel, logit
from glimpse.render.projection import quat_to_rotation

SPLIT_COUNT = 2  # a split Gaussian becomes this many (3DGS: N = 2)
SPLIT_SCALE_DIVISOR = 1.6  # their scales are the parent's divided by this (3DGS: 0.8 * N)


def screen_threshold(grad_threshold: float, reference_height_px: float, height: int) -> float:
    """The gradient threshold for images ``height`` pixels tall: a Gaussian of a given size in pixels
    gets an NDC gradient proportional to 1 / height from a loss averaged over pixels, so the threshold,
    given at ``reference_height_px``, scales with reference / height (0: no scaling, as 3DGS)."""
    return grad_threshold * (reference_height_px / height if reference_height_px > 0 else 1.0)


@dataclass(frozen=True)
class DensifyConfig:
    """Schedule (iterations, already multiplied by schedule_scale) and thresholds; pipeline.yaml
    documents each."""

    start: int
    stop: int
    every: int
    grad_threshold: float
    reference_height_px: float
    percent_dense: float
    min_opacity: float
    max_screen_px: float
    max_world_fraction: float
    opacity_reset_every: int
    opacity_reset_value: float
    max_gaussians: int

    def threshold_at(self, height: int) -> float:
        return screen_threshold(self.grad_threshold, self.reference_height_px, height)

    def densifies_at(self, step: int) -> bool:
        """``step`` counts completed iterations (1-based, 3DGS's ``iteration``)."""
        return self.start < step < self.stop and step % self.every == 0

    def resets_opacity_at(self, step: int) -> bool:
        return step < self.stop and step % self.opacity_reset_every == 0

    def prunes_large_at(self, step: int) -> bool:
        """Screen- and world-size pruning starts after the first opacity reset (3DGS)."""
        return step > self.opacity_reset_every


class DensityStats:
    """Per-Gaussian statistics gathered between densifications."""

    def __init__(self, count: int, device: torch.device | str = "cpu"):
        self.grad_sum = torch.zeros(count, device=device)  # summed NDC gradient norms
        self.views = torch.zeros(count, device=device)  # renders in which the Gaussian was drawn
        self.max_radii = torch.zeros(count, device=device)  # largest screen radius, pixels

    def update(self, means2d_grad: Tensor, radii: Tensor, width: int, height: int) -> None:
        """Add one render: ``means2d_grad [N, 2]`` (d loss / d pixel), ``radii [N]`` (0 = not drawn)."""
        drawn = radii > 0
        scale = torch.tensor([width / 2.0, height / 2.0], device=means2d_grad.device)
        norms = (means2d_grad * scale).norm(dim=-1)
        self.grad_sum[drawn] += norms[drawn]
        self.views[drawn] += 1
        self.max_radii[drawn] = torch.maximum(self.max_radii[drawn], radii[drawn].to(self.max_radii))

    def reset(self, count: int) -> None:
        """Start gathering afresh for ``count`` Gaussians (after a densification)."""
        self.__init__(count, self.grad_sum.device)

    def keep(self, rows: Tensor) -> None:
        """Keep the statistics of the Gaussians where ``rows [N]`` (bool) is True (after a pruning)."""
        self.grad_sum, self.views, self.max_radii = self.grad_sum[rows], self.views[rows], self.max_radii[rows]

    def mean_grad(self) -> Tensor:
        return torch.where(self.views > 0, self.grad_sum / self.views.clamp(min=1), torch.zeros_like(self.grad_sum))

    def state_dict(self) -> dict[str, Tensor]:
        return {"grad_sum": self.grad_sum, "views": self.views, "max_radii": self.max_radii}

    def load_state_dict(self, state: dict[str, Tensor]) -> None:
        self.grad_sum, self.views, self.max_radii = state["grad_sum"], state["views"], state["max_radii"]


def reindex(model: GaussianModel, optimizer: torch.optim.Optimizer, tensors: dict[str, Tensor], source: Tensor,
            fresh: Tensor) -> None:
    """Replace every parameter by ``tensors[name]`` ([M, ...]) whose row m derives from old row
    ``source[m]``; Adam moments are carried over from there, or zeroed where ``fresh[m]``."""
    new_params = {name: nn.Parameter(tensors[name].detach().contiguous()) for name in PARAMETER_NAMES}
    for group in optimizer.param_groups:
        old = group["params"][0]
        new = new_params[group["name"]]
        state = optimizer.state.pop(old, None)
        if state:
            for key in ("exp_avg", "exp_avg_sq"):
                moments = state[key][source].clone()
                moments[fresh] = 0.0
                state[key] = moments
            optimizer.state[new] = state
        group["params"][0] = new
    model.replace_parameters(new_params)


def keep_only(model: GaussianModel, optimizer: torch.optim.Optimizer, keep: Tensor) -> None:
    """Drop the Gaussians where ``keep [N]`` is False."""
    index = torch.nonzero(keep).squeeze(1)
    tensors = {name: param.detach()[index] for name, param in model.parameter_dict().items()}
    reindex(model, optimizer, tensors, index, torch.zeros(len(index), dtype=torch.bool, device=index.device))


def densify(model: GaussianModel, optimizer: torch.optim.Optimizer, stats: DensityStats, threshold: float,
            split_above: float, max_gaussians: int, generator: torch.Generator) -> tuple[dict, Tensor]:
    """Clone the small and split the large (largest scale above ``split_above``, world units) of the Gaussians
    whose mean screen gradient reaches ``threshold``, keeping at most ``max_gaussians`` (0: no cap). Returns the
    counts and the largest screen radius [N'] of each Gaussian afterwards (0 for the new ones); ``stats`` must be
    reset afterwards."""
    grads = stats.mean_grad()
    with torch.no_grad():
        largest = model.scales().max(dim=1).values
        wanted = grads >= threshold
        budget = max(max_gaussians - len(model), 0) if max_gaussians > 0 else len(model) * SPLIT_COUNT
        if int(wanted.sum()) * (SPLIT_COUNT - 1) > budget:  # over the cap: keep the largest gradients
            order = torch.argsort(torch.where(wanted, grads, torch.full_like(grads, -1.0)), descending=True)
            wanted = torch.zeros_like(wanted)
            wanted[order[: budget // (SPLIT_COUNT - 1)]] = True
        small = largest <= split_above
        clone, split = wanted & small, wanted & ~small
        params = {name: param.detach() for name, param in model.parameter_dict().items()}
        clone_idx, split_idx = torch.nonzero(clone).squeeze(1), torch.nonzero(split).squeeze(1)
        children = _split_children(params, split_idx, generator)
        kept_idx = torch.nonzero(~split).squeeze(1)
        tensors = {name: torch.cat([params[name][kept_idx], params[name][clone_idx], children[name]])
                   for name in PARAMETER_NAMES}
        source = torch.cat([kept_idx, clone_idx, split_idx.repeat(SPLIT_COUNT)])
        fresh = torch.cat([torch.zeros(len(kept_idx), dtype=torch.bool, device=source.device),
                           torch.ones(len(clone_idx) + SPLIT_COUNT * len(split_idx), dtype=torch.bool,
                                      device=source.device)])
        reindex(model, optimizer, tensors, source, fresh)
        radii = torch.cat([stats.max_radii[kept_idx], torch.zeros(len(source) - len(kept_idx), device=source.device)])
    return {"cloned": len(clone_idx), "split": len(split_idx)}, radii


def densify_and_prune(model: GaussianModel, optimizer: torch.optim.Optimizer, stats: DensityStats,
                      config: DensifyConfig, extent: float, height: int, prune_large: bool,
                      generator: torch.Generator) -> dict:
    """One densification of 3DGS: clone, split, then prune the transparent and, with ``prune_large``, those too
    large on screen or in the world (``height``: of the training images, pixels; ``extent``: the scene's, world
    units). Returns counts; ``stats`` must be reset afterwards."""
    counts, radii = densify(model, optimizer, stats, config.threshold_at(height), config.percent_dense * extent,
                            config.max_gaussians, generator)
    with torch.no_grad():
        prune = model.opacities() < config.min_opacity
        if prune_large:
            prune |= radii > config.max_screen_px
            prune |= model.scales().max(dim=1).values > config.max_world_fraction * extent
        keep_only(model, optimizer, ~prune)
    return {**counts, "pruned": int(prune.sum()), "count": len(model)}


def _split_children(params: dict[str, Tensor], index: Tensor, generator: torch.Generator) -> dict[str, Tensor]:
    """``SPLIT_COUNT`` children per parent in ``index``: means sampled from the parent Gaussian,
    scales divided by ``SPLIT_SCALE_DIVISOR``, everything else copied."""
    scales = torch.exp(params["log_scales"][index]).repeat(SPLIT_COUNT, 1)
    rotations = quat_to_rotation(params["quats"][index]).repeat(SPLIT_COUNT, 1, 1)
    offsets = torch.randn(scales.shape, generator=generator, device=generator.device).to(scales) * scales
    children = {name: params[name][index].repeat(SPLIT_COUNT, *([1] * (params[name].dim() - 1)))
                for name in PARAMETER_NAMES}
    children["means"] = children["means"] + (rotations @ offsets[..., None]).squeeze(-1)
    children["log_scales"] = torch.log(scales / SPLIT_SCALE_DIVISOR)
    return children


def reset_opacity(model: GaussianModel, optimizer: torch.optim.Optimizer, ceiling: float) -> None:
    """Opacities above ``ceiling`` drop to it (in place); the opacity's Adam moments restart (3DGS)."""
    with torch.no_grad():
        model.opacity_logits.clamp_(max=logit(ceiling))
    state = optimizer.state.get(model.opacity_logits)
    if state:
        state["exp_avg"].zero_()
        state["exp_avg_sq"].zero_()
