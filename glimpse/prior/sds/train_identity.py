"""Stage 05's identity training: CustomDiffusion on one person's crops (glimpse/prior/sds/identity.py).

Each step draws ``batch_size`` crops, encodes them with the VAE (no gradients), adds noise at
uniformly random timesteps, and predicts it with the UNet (the crop's view prompt with the
person's token; that person's K/V processors) steered by the frozen ControlNet (the skeleton image,
the prompt without the token). The loss is the MSE between predicted and true noise, per latent
pixel weighted 1 on the person (the crop's soft mask) and ``background_weight`` elsewhere (1: plain
CustomDiffusion; official code 0.5). Adam updates the token's embedding row and the K/V projections
only: the other embedding rows are restored after every step.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from glimpse.errors import ConfigError
from glimpse.prior.sds.guidance import DiffusionModels, add_noise, encode_images, encode_text, text_states
from glimpse.prior.sds.identity import TRAINABLE_DTYPE, IdentitySwitch, PersonIdentity


@dataclass(frozen=True)
class SampleConfig:
    count: int             # samples in the grid (0: none)
    steps: int             # DDIM steps per sample
    guidance_scale: float  # classifier-free guidance of the samples (SD's usual 7.5)


@dataclass(frozen=True)
class IdentityConfig:
    steps: int                 # optimisation steps per person (paper: 1000)
    learning_rate: float       # Adam, token row and K/V (paper: 5e-6; official code: 1e-5)
    batch_size: int            # crops per step (paper: 4; official code: 2)
    background_weight: float   # loss weight off the person's mask (1: plain; official code: 0.5)
    controlnet_scale: float    # the ControlNet's residual weight while training (official code: 1.0)
    reference_prompt: str      # the prompt of reference photos, with {token}
    samples: SampleConfig      # the grid of samples written after training

    def __post_init__(self) -> None:
        if self.steps < 0 or self.batch_size < 1 or self.learning_rate <= 0:
            raise ConfigError("pipeline.yaml 05_textual_inversion.identity: need steps >= 0, batch_size >= 1 and "
                              "learning_rate > 0")


@dataclass
class IdentityExample:
    """One training crop: image [3, S, S] and skeleton [3, S, S] in 0..1, mask [S, S] in 0..1, and the
    UNet's prompt (with the token) and the ControlNet's (without)."""

    image: Tensor
    mask: Tensor
    skeleton: Tensor
    prompt: str
    control_prompt: str


def identity_loss(models: DiffusionModels, examples: list[IdentityExample], timesteps: Tensor, noise: Tensor,
                  config: IdentityConfig) -> Tensor:
    """The weighted noise-prediction MSE of one batch at ``timesteps [B]`` with ``noise [B, C, h, w]``
    (gradients reach the token's embedding and whatever attention processors the UNet holds)."""
    images = torch.stack([e.image for e in examples]).to(models.device)
    skeletons = torch.stack([e.skeleton for e in examples]).to(models.device, models.dtype)
    with torch.no_grad():
        latents = encode_images(models, images)
        noisy = add_noise(models, latents, noise, timesteps)
        control_text = encode_text(models, [e.control_prompt for e in examples])
        down, middle = models.controlnet(noisy, timesteps, encoder_hidden_states=control_text,
                                         controlnet_cond=skeletons, conditioning_scale=config.controlnet_scale,
                                         return_dict=False)
    text = text_states(models, [e.prompt for e in examples])
    predicted = models.unet(noisy, timesteps, encoder_hidden_states=text, down_block_additional_residuals=down,
                            mid_block_additional_residual=middle, return_dict=False)[0]
    masks = torch.stack([e.mask for e in examples]).to(models.device)[:, None].float()
    on_person = F.interpolate(masks, size=latents.shape[-2:], mode="area")
    weight = on_person + config.background_weight * (1.0 - on_person)
    return ((predicted.float() - noise.float()).square() * weight).mean()


def train_identity(models: DiffusionModels, identity: PersonIdentity, examples: list[IdentityExample],
                   config: IdentityConfig, generator: torch.Generator,
                   progress: Callable[[int, float], None] | None = None) -> list[float]:
    """Train ``identity`` on ``examples`` for ``config.steps`` steps; the loss of every step."""
    switch = IdentitySwitch(models.unet)
    switch.use(identity)
    embedding = models.text_encoder.get_input_embeddings()
    # the token's row is trained as a float32 copy that the embedding's output takes in (a float16 table
    # would lose Adam's steps); the other rows never change
    token_row = nn.Parameter(embedding.weight[identity.token_id].detach().to(TRAINABLE_DTYPE).clone())
    hook = embedding.register_forward_hook(_with_row(identity.token_id, token_row))
    kv = identity.kv_parameters()
    for parameter in kv:
        parameter.requires_grad_(True)
    optimizer = torch.optim.Adam([token_row, *kv], lr=config.learning_rate)
    losses = []
    try:
        for step in range(config.steps):
            picks = torch.randint(len(examples), (config.batch_size,), generator=generator).tolist()
            timesteps = torch.randint(models.train_timesteps, (len(picks),), generator=generator).to(models.device)
            batch = [examples[k] for k in picks]
            size = batch[0].image.shape[-1] // models.vae_scale_factor
            channels = models.unet.config.in_channels
            noise = torch.randn(len(picks), channels, size, size, generator=generator).to(models.device, models.dtype)
            loss = identity_loss(models, batch, timesteps, noise, config)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            losses.append(float(loss.detach()))
            if progress is not None:
                progress(step, losses[-1])
    finally:
        hook.remove()
        with torch.no_grad():
            embedding.weight[identity.token_id] = token_row.to(embedding.weight.dtype)
        for parameter in kv:
            parameter.requires_grad_(False)
        switch.use(None)
    return losses


def _with_row(token_id: int, row: Tensor):
    """A forward hook for the text encoder's token embedding: where the input is ``token_id``, the output is
    ``row`` (differentiable, cast to the output's dtype)."""

    def hook(module: nn.Module, inputs: tuple, output: Tensor) -> Tensor:
        at_token = (inputs[0] == token_id)[..., None]
        return torch.where(at_token, row.to(output.dtype), output) if bool(at_token.any()) else output

    return hook
