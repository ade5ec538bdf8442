"""The joint optimisation loop (paper Sec. 4.5): every person's canonical Gaussians and the
background, trained together on the input frames.

Each iteration renders one input frame (frames in a fresh seeded order every epoch) with every
person present posed by that frame's (refined) pose, in one rasterizer call, and minimises

    lambda_recon * (mse * MSE + dssim * D-SSIM + lpips * LPIPS   (over pixels no static occluder hides)
                    + hard_surface * sum_k mean(hard_surface(alpha_k)))  (each person's alpha, same pixels)
  + the prior's terms

(lambda_recon = 1 unless the prior schedules it: the sds prior's 1e6 tau_max^2); then the prior's
separate losses, if any, each take their own step on one person's optimiser (the official SDS).

Schedule (all scaled by schedule_scale): human means fixed and opacities >= early_min_opacity
until fix_centres_until; human densification at densify_at; pruning of transparent, large or
escaped human Gaussians every prune_every after that; the humans' SH degree grows every
sh_degree_every. The background keeps its count. The loop itself (resume, checkpoints, progress,
loss history) is glimpse.gaussians.trainer's. Everything random is a function of (seed, iteration),
and checkpoints hold every changing state, so a resumed run ends as an uninterrupted one.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch
from torch import Tensor

from glimpse.gaussians.model import GaussianModel, logit
from glimpse.gaussians.optim import make_optimizer, set_position_lr
from glimpse.gaussians.trainer import GaussianTrainer
from glimpse.gaussians.training import SEED_STRIDE, scene_extent, training_background
from glimpse.humans.compose import frame_gaussians, render_frame
from glimpse.humans.person import PersonGaussians
from glimpse.joint.config import JointConfig
from glimpse.metrics.losses import (
    dssim_loss_on,
    hard_surface_loss,
    lpips_loss,
    lpips_loss_target,
    lpips_loss_to_features,
    mse_loss,
)
from glimpse.metrics.lpips import LPIPS
from glimpse.prior.base import UnseenPrior
from glimpse.render import Camera, RenderOutput
from glimpse.render.config import RenderConfig

HUMAN_EXTENT = 1.0  # canonical frame: human learning rates are in metres of body
PERSON_SEED_STRIDE = 101  # person k's densification at iteration i draws from seed * SEED_STRIDE + i * stride + k


Box = tuple[int, int, int, int]
LPIPS_TARGET = "lpips_target"  # JointView.derived's key of the LPIPS target features


@dataclass
class JointView:
    """One input frame: camera, and ``pixels(frame_id)`` -> its image [H, W, 3] uint8, the pixels the losses
    use ``keep [H, W]`` bool, the LPIPS box ``(y0, y1, x0, x1)`` around its people (None: nobody visible) and
    a dict for what the trainer derives from them once (the LPIPS target's features); ``pixels`` is the stage's
    FrameCache (read from disk when needed, a bounded number kept, the derived values with them)."""

    frame_id: int
    camera: Camera
    pixels: Callable[[int], tuple[Tensor, Tensor, Box | None, dict[str, Any]]]

    @property
    def image(self) -> Tensor:
        return self.pixels(self.frame_id)[0]

    @property
    def keep(self) -> Tensor:
        return self.pixels(self.frame_id)[1]

    @property
    def people_box(self) -> Box | None:
        return self.pixels(self.frame_id)[2]

    @property
    def derived(self) -> dict[str, Any]:
        return self.pixels(self.frame_id)[3]

    def target(self) -> Tensor:
        return self.image.float() / 255.0


def reconstruction_terms(config: JointConfig, lpips_module: LPIPS | None, rendered: Tensor, target: Tensor,
                         keep: Tensor, box: Box | None, lpips_target: list[Tensor] | None = None
                         ) -> dict[str, Tensor]:
    """Unweighted MSE, D-SSIM and (inside ``box``) LPIPS of ``rendered`` vs ``target`` [H, W, 3] over ``keep``;
    ``lpips_target``: :func:`lpips_target_features` of this target, when kept from an earlier iteration."""
    terms = {"mse": mse_loss(rendered, target, keep), "dssim": dssim_loss_on(rendered, target, keep)}
    if config.loss.lpips > 0 and lpips_module is not None and box is not None:
        y0, y1, x0, x1 = box
        pred, inside = rendered[y0:y1, x0:x1], keep[y0:y1, x0:x1]
        terms["lpips"] = (lpips_loss(lpips_module, pred, target[y0:y1, x0:x1], inside) if lpips_target is None
                          else lpips_loss_to_features(lpips_module, pred, lpips_target, inside))
    return terms


def lpips_target_features(lpips_module: LPIPS, target: Tensor, keep: Tensor, box: Box) -> list[Tensor]:
    """The LPIPS features ``reconstruction_terms`` compares the render with: ``target [H, W, 3]`` inside ``box``,
    black where ``keep`` is not set."""
    y0, y1, x0, x1 = box
    return lpips_loss_target(lpips_module, target[y0:y1, x0:x1], keep[y0:y1, x0:x1])


class JointTrainer(GaussianTrainer):
    """Trains ``people`` and ``background`` on ``views`` (checkpoints, resume and progress: GaussianTrainer)."""

    name = "06 joint"

    def __init__(self, background: GaussianModel, people: list[PersonGaussians], views: list[JointView],
                 config: JointConfig, render: RenderConfig, prior: UnseenPrior, lpips_module: LPIPS | None,
                 seed: int, checkpoint: Path, key: str, lpips_target_cache_mb: float = 0.0):
        super().__init__(config.total_iterations, config.checkpoint_every, checkpoint, key, background.means.device)
        self.background, self.people, self.views, self.config, self.render = background, people, views, config, render
        self.prior, self.lpips, self.seed = prior, lpips_module, seed
        self.lpips_target_bytes_left = int(lpips_target_cache_mb * 2**20)  # what may still be kept (never returned)
        self.background_degree = min(background.sh_degree, render.sh_degree)
        self.extent = scene_extent([v.camera for v in views], background.means.detach())
        self.background_rates = config.scaled_rates(config.background_lr)
        self.human_rates = config.scaled_rates(config.lr)
        self.strategy = config.people_strategy()
        self._make_optimizers()
        self.stats = [self.strategy.initialize_state(p.model) for p in people]

    def _make_optimizers(self) -> None:
        self.background_optimizer = make_optimizer(self.background, self.background_rates, self.extent)
        self.person_optimizers = [make_optimizer(p.model, self.human_rates, HUMAN_EXTENT) for p in self.people]
        self.pose_optimizer = (torch.optim.Adam([p.pose_offsets for p in self.people], lr=self.config.pose_lr)
                               if self.config.refine_pose and self.people else None)

    def _optimizers(self) -> list[torch.optim.Optimizer]:
        extra = [self.pose_optimizer] if self.pose_optimizer is not None else []
        return [self.background_optimizer, *self.person_optimizers, *extra]

    # --- checkpoints -------------------------------------------------------------------------

    def _state(self) -> dict:
        def params(model: GaussianModel) -> dict:
            return {k: v.detach().cpu() for k, v in model.parameter_dict().items()}

        return {"background": params(self.background),
                "people": [{"parameters": params(p.model), "pose_offsets": p.pose_offsets.detach().cpu()}
                           for p in self.people],
                "optimizers": [o.state_dict() for o in self._optimizers()],
                "stats": [{k: v.cpu() for k, v in s.state_dict().items()} for s in self.stats],
                "prior": self.prior.state_dict()}

    def _restore(self, state: dict) -> None:
        device = self.background.means.device
        self.background.replace_parameters({k: v.to(device) for k, v in state["background"].items()})
        for person, saved in zip(self.people, state["people"]):
            person.model.replace_parameters({k: v.to(device) for k, v in saved["parameters"].items()})
            with torch.no_grad():
                person.pose_offsets.copy_(saved["pose_offsets"])
        self._make_optimizers()
        for optimizer, saved in zip(self._optimizers(), state["optimizers"]):
            optimizer.load_state_dict(saved)
        for stats, saved in zip(self.stats, state["stats"]):
            stats.load_state_dict({k: v.to(device) for k, v in saved.items()})
        self.prior.load_state_dict(state["prior"])

    def _history_entry(self, values: dict[str, float]) -> dict:
        return {"iteration": self.step, **{k: round(v, 6) for k, v in values.items()}}

    def _counts(self) -> str:
        return "human Gaussians " + "/".join(str(len(p.model)) for p in self.people)

    def _progress(self, values: dict[str, float]) -> dict[str, str]:
        return {"loss": f"{values['total']:.4f}", "mse": f"{values['mse']:.4f}",
                "humans": "/".join(str(len(p.model)) for p in self.people)}

    # --- one iteration -----------------------------------------------------------------------

    def _iteration(self) -> dict[str, float]:
        step, config = self.step + 1, self.config
        set_position_lr(self.background_optimizer, self.background_rates, self.extent, step)
        for optimizer in self.person_optimizers:
            set_position_lr(optimizer, self.human_rates, HUMAN_EXTENT, step)
        with self.phases("data"):
            view = self._view(self.views, self.seed, step)
            view.pixels(view.frame_id)  # read (or take from the cache) the frame and its masks
        human_degree = config.human_sh_degree(step, self.render.sh_degree)
        with self.phases("pose"):
            gaussians = frame_gaussians(view.camera, view.frame_id, self.people, human_degree, self.background,
                                        self.background_degree)
        with self.phases("render"):
            colour = training_background(config.background_colour, self.seed, step, view.image.device)
            out = render_frame(view.camera, gaussians, len(self.people), self.render, colour)
            out.means2d.retain_grad()
        present = list(gaussians.rows)
        with self.phases("loss"):
            total, terms = self._loss(step, view, out, present)
        with self.phases("backward"):
            total.backward()
        fixed = config.centres_fixed_at(step)
        with torch.no_grad():
            with self.phases("densify"):
                weight = self.prior.recon_weight(step)  # densification reads gradients of the unweighted loss
                for k, rows in gaussians.rows.items():
                    if out.means2d.grad is not None:
                        self.strategy.observe(self.stats[k], out.means2d.grad[rows] / weight, out.radii[rows],
                                              view.camera.width, view.camera.height, step)
            with self.phases("optimiser"):
                self._step(self._optimizers(), fixed)
        with self.phases("prior"):
            separate = self._separate_steps(step, fixed)
        with torch.no_grad(), self.phases("densify"):
            self._density_control(step, view.camera.height)
        self.step = step
        values = {name: float(value.detach()) for name, value in terms.items()}
        values.update(separate)
        values["total"] = float(total.detach()) + sum(separate.values())
        return values

    @torch.no_grad()
    def _step(self, optimizers: list, fixed: bool) -> None:
        """One step of ``optimizers``; while the human centres are fixed their means do not move and their
        opacities stay at or above early_min_opacity."""
        if fixed:
            for person in self.people:
                person.model.means.grad = None
        for optimizer in optimizers:
            optimizer.step()
            optimizer.zero_grad(set_to_none=True)
        if fixed and self.config.early_min_opacity > 0:
            for person in self.people:
                person.model.opacity_logits.clamp_(min=logit(self.config.early_min_opacity))

    def _separate_steps(self, step: int, fixed: bool) -> dict[str, float]:
        """The prior's own per-person steps after the iteration's (the official code's SDS): each loss
        backpropagated alone and that person's optimiser stepped; {"loss_<prior>_separate": their sum}."""
        total, count = 0.0, 0
        for index, loss in self.prior.separate_losses(step):
            loss.backward()
            self._step([self.person_optimizers[index]], fixed)
            total, count = total + float(loss.detach()), count + 1
        return {f"loss_{self.prior.name}_separate": total} if count else {}

    def _loss(self, step: int, view: JointView, out: RenderOutput, present: list[int]) -> tuple[Tensor, dict]:
        """The total loss and its unweighted terms (the prior's come weighted) for one render."""
        weights = self.config.loss
        terms = reconstruction_terms(self.config, self.lpips, out.rgb, view.target(), view.keep, view.people_box,
                                     self._lpips_target(view))
        total = sum(getattr(weights, name) * value for name, value in terms.items())
        if present and weights.hard_surface > 0:
            terms["hard_surface"] = sum(hard_surface_loss(out.group_alpha[1 + k], view.keep) for k in present)
            total = total + weights.hard_surface * terms["hard_surface"]
        total = self.prior.recon_weight(step) * total  # the hard-surface term stays 0.1 of it (paper)
        prior_terms = self.prior.losses(step, [self.people[k] for k in present])
        terms.update(prior_terms)
        return total + sum(prior_terms.values()), terms

    def _lpips_target(self, view: JointView) -> list[Tensor] | None:
        """The view's LPIPS target features, kept with its pixels while ``lpips_target_cache_mb`` lasts (half of the
        LPIPS forward pass; about 0.6 MB a frame for AlexNet at a 150x100 box). The budget counts every set kept,
        also those the frame cache has since dropped, so the features never hold more than it. None: no LPIPS."""
        if self.lpips is None or self.config.loss.lpips <= 0 or view.people_box is None:
            return None
        derived = view.derived
        if LPIPS_TARGET in derived:
            return derived[LPIPS_TARGET]
        features = lpips_target_features(self.lpips, view.target(), view.keep, view.people_box)
        size = sum(f.numel() * f.element_size() for f in features)
        if size <= self.lpips_target_bytes_left:
            self.lpips_target_bytes_left -= size
            derived[LPIPS_TARGET] = features
        return features

    def _density_control(self, step: int, height: int) -> None:
        """Each person's densification and pruning, as the people's strategy schedules them; Gaussians that
        leave the person's skinning grid are pruned."""
        for k, (person, optimizer) in enumerate(zip(self.people, self.person_optimizers)):
            event = self.strategy.adapt(person.model, optimizer, self.stats[k], step, height,
                                        self.seed * SEED_STRIDE + step * PERSON_SEED_STRIDE + k, person.grid.inside)
            if event is not None:
                self.log.densify_events.append({"iteration": step, "person": person.pid, **event})
                self.prior.gaussians_changed(person)


def people_box(union: np.ndarray, margin_px: int, min_px: int) -> Box | None:
    """(y0, y1, x0, x1): the box around the True pixels of ``union [H, W]``, grown by ``margin_px`` and to at
    least ``min_px`` a side (within the image); None when nothing is set."""
    ys, xs = np.nonzero(union)
    if len(ys) == 0:
        return None
    height, width = union.shape

    def span(lo: int, hi: int, size: int) -> tuple[int, int]:
        lo, hi = max(lo - margin_px, 0), min(hi + 1 + margin_px, size)
        grow = max(min(min_px, size) - (hi - lo), 0)
        lo = max(lo - (grow + 1) // 2, 0)
        hi = min(lo + max(hi - lo, min(min_px, size)), size)
        return max(min(lo, hi - min(min_px, size)), 0), hi

    y0, y1 = span(int(ys.min()), int(ys.max()), height)
    x0, x1 = span(int(xs.min()), int(xs.max()), width)
    return y0, y1, x0, x1
