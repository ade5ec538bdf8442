"""The background training loop (3DGS's ``train.py`` restricted to background pixels).

Each iteration renders one input view (frames in a fresh seeded order every epoch) over a
background colour, compares it with the frame on the pixels no person covers:
``(1 - w) * L1 (or MSE) + w * D-SSIM``, plus, for a sphere start, the radius regulariser
``lambda * sum((|mu - c| - R)^2)``. Adam steps every parameter; adaptive density control
and opacity resets follow the schedule; the active SH degree grows over time.

The loop itself (resume, checkpoints, progress, loss history) is glimpse.gaussians.trainer's.
Everything random is a function of (seed, iteration), and the state that changes is saved in
checkpoints, so a run resumed from a checkpoint gives the same result as one never stopped.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import torch
from torch import Tensor

from glimpse.background.config import BackgroundConfig
from glimpse.background.init import Sphere
from glimpse.gaussians.model import GaussianModel
from glimpse.gaussians.optim import make_optimizer, set_position_lr
from glimpse.gaussians.strategy import DefaultStrategy
from glimpse.gaussians.trainer import GaussianTrainer
from glimpse.gaussians.training import SEED_STRIDE, scene_extent, training_background
from glimpse.metrics.losses import dssim_loss_on, l1_loss, mse_loss
from glimpse.render import Camera, rasterize
from glimpse.render.config import RenderConfig


@dataclass
class TrainingView:
    """One input frame: its camera, and ``pixels(frame_id)`` -> its image [H, W, 3] uint8 and the pixels trained
    on, background [H, W] bool (the stage's FrameCache: read from disk when needed, a bounded number kept)."""

    frame_id: int
    camera: Camera
    pixels: Callable[[int], tuple[Tensor, Tensor]]

    @property
    def image(self) -> Tensor:
        return self.pixels(self.frame_id)[0]

    @property
    def background(self) -> Tensor:
        return self.pixels(self.frame_id)[1]

    def target(self) -> Tensor:
        return self.image.float() / 255.0


def photometric_loss(config: BackgroundConfig, rendered: Tensor, target: Tensor, background: Tensor) -> Tensor:
    """Loss over background pixels. For D-SSIM, pixels outside them are set to the (detached) render in
    both images, so people never enter an SSIM window."""
    pixel = l1_loss if config.photometric == "l1" else mse_loss
    loss = pixel(rendered, target, background)
    if config.dssim_weight > 0:
        loss = (1.0 - config.dssim_weight) * loss + config.dssim_weight * dssim_loss_on(rendered, target, background)
    return loss


def sphere_regulariser(means: Tensor, sphere: Sphere, weight: float) -> Tensor:
    centre = torch.as_tensor(sphere.centre, dtype=means.dtype, device=means.device)
    return weight * ((means - centre).norm(dim=1) - sphere.radius).square().sum()


class BackgroundTrainer(GaussianTrainer):
    """Trains ``model`` on ``views`` (checkpoints, resume and progress: GaussianTrainer)."""

    name = "04 background"

    def __init__(self, model: GaussianModel, views: list[TrainingView], config: BackgroundConfig,
                 render: RenderConfig, sphere: Sphere | None, seed: int, checkpoint: Path, key: str):
        super().__init__(config.total_iterations, config.checkpoint_every, checkpoint, key, model.means.device)
        self.model, self.views, self.config, self.render = model, views, config, render
        self.sphere, self.seed = sphere, seed
        self.extent = scene_extent([v.camera for v in views], model.means.detach())
        self.rates, self.strategy = config.scaled_lr, DefaultStrategy(config.scaled_densify, self.extent)
        self.optimizer = make_optimizer(model, self.rates, self.extent)
        self.stats = self.strategy.initialize_state(model)

    # --- checkpoints -------------------------------------------------------------------------

    def _state(self) -> dict:
        return {"parameters": {k: v.detach().cpu() for k, v in self.model.parameter_dict().items()},
                "optimizer": self.optimizer.state_dict(), "stats": {k: v.cpu() for k, v in self.stats.state_dict().items()}}

    def _restore(self, state: dict) -> None:
        device = self.model.means.device
        self.model.replace_parameters({k: v.to(device) for k, v in state["parameters"].items()})
        self.optimizer = make_optimizer(self.model, self.rates, self.extent)
        self.optimizer.load_state_dict(state["optimizer"])
        self.stats.load_state_dict({k: v.to(device) for k, v in state["stats"].items()})

    def _history_entry(self, values: dict[str, float]) -> tuple[int, float]:
        return self.step, round(values["total"], 6)

    def _counts(self) -> str:
        return f"{len(self.model)} Gaussians"

    def _progress(self, values: dict[str, float]) -> dict[str, str]:
        return {"loss": f"{values['total']:.4f}", "gaussians": str(len(self.model))}

    # --- one iteration -----------------------------------------------------------------------

    def _iteration(self) -> dict[str, float]:
        step, config = self.step + 1, self.config
        set_position_lr(self.optimizer, self.rates, self.extent, step)
        with self.phases("data"):
            view = self._view(self.views, self.seed, step)
            target, background = view.target(), view.background
        degree = min((step - 1) // config.scaled_sh_degree_every, self.render.sh_degree)
        with self.phases("render"):
            out = rasterize(view.camera, **self.model.render_inputs(degree),
                            background=training_background(config.background_colour, self.seed, step, target.device),
                            settings=self.render)
            out.means2d.retain_grad()
        with self.phases("loss"):
            loss = photometric_loss(config, out.rgb, target, background)
            total = loss + sphere_regulariser(self.model.means, self.sphere, config.sphere_reg_weight) if self.sphere else loss
        with self.phases("backward"):
            total.backward()
        with torch.no_grad():
            with self.phases("densify"):
                if out.means2d.grad is not None:
                    self.strategy.observe(self.stats, out.means2d.grad, out.radii, view.camera.width,
                                          view.camera.height, step)
            with self.phases("optimiser"):
                self.optimizer.step()
                self.optimizer.zero_grad(set_to_none=True)
            with self.phases("densify"):
                self._density_control(step)
        self.step = step
        return {"total": float(loss.detach())}

    def _density_control(self, step: int) -> None:
        event = self.strategy.adapt(self.model, self.optimizer, self.stats, step, self.views[0].camera.height,
                                    self.seed * SEED_STRIDE + step)
        if event is not None:
            self.log.densify_events.append({"iteration": step, **event})
