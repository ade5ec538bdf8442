"""Score distillation from Stable Diffusion with an OpenPose ControlNet (paper Sec. 4.4; DreamFusion).

One SDS step on a batch of renders of one person: the renders (RGB in 0..1) are resized to the
diffusion's resolution and encoded by the VAE (gradients flow through the encoder); noise at
timestep t is added; the UNet, steered by the ControlNet reading the skeleton image, predicts the
noise with the prompt and with the negative prompt; classifier-free guidance combines them,
eps_hat = eps_neg + g (eps_cond - eps_neg); the gradient w(t) (eps_hat - eps), w(t) = 1 - alpha_bar_t,
goes into the latents through 0.5 |z - sg(z - grad)|^2 (its gradient in z is exactly that), with NaNs
and infinities zeroed (GTU_REFERENCE.md 4). The UNet and ControlNet run without gradients.

The models are diffusers modules (UNet2DConditionModel, ControlNetModel, AutoencoderKL,
CLIPTextModel and its tokenizer) plus the training noise schedule's cumulative alphas; each
person's identity (token embedding, cross-attention K/V) is swapped into them before their step.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor


@dataclass
class DiffusionModels:
    """The shared diffusion parts (one set for every person), frozen, on ``device``."""

    unet: Any            # diffusers UNet2DConditionModel
    controlnet: Any      # diffusers ControlNetModel
    vae: Any             # diffusers AutoencoderKL
    text_encoder: Any    # transformers CLIPTextModel
    tokenizer: Any       # transformers CLIPTokenizer
    scheduler: Any       # the training noise schedule (a diffusers scheduler; its alphas_cumprod)
    device: torch.device
    alphas_cumprod: Tensor = field(init=False)  # [T] cumulative products of alpha, on device, float32

    def __post_init__(self) -> None:
        self.alphas_cumprod = torch.as_tensor(self.scheduler.alphas_cumprod).to(self.device, torch.float32)

    @property
    def dtype(self) -> torch.dtype:
        return self.unet.dtype

    @property
    def train_timesteps(self) -> int:
        return len(self.alphas_cumprod)

    @property
    def vae_scale_factor(self) -> int:
        """Image pixels per latent pixel (SD 1.5: 8)."""
        return 2 ** (len(self.vae.config.block_out_channels) - 1)


@dataclass(frozen=True)
class SDSConfig:
    guidance_scale: float      # classifier-free guidance (paper: 50)
    controlnet_scale: float    # weight of the ControlNet's residuals (official code: 0.7)
    resolution_px: int         # renders are resized to this square before the VAE (SD 1.5: 512)


@dataclass
class SDSText:
    """Encoded prompts of one view, [1, L, D] each: the UNet's (with the token), the ControlNet's (without)
    and the negative prompt (both networks' unconditional branch)."""

    unet: Tensor
    controlnet: Tensor
    negative: Tensor


def text_states(models: DiffusionModels, texts: list[str]) -> Tensor:
    """[len(texts), L, D] the text encoder's last hidden states, padded to the tokenizer's length (with
    gradients, where the encoder has any: identity training)."""
    tokens = models.tokenizer(texts, padding="max_length", max_length=models.tokenizer.model_max_length,
                              truncation=True, return_tensors="pt").input_ids.to(models.device)
    return models.text_encoder(tokens)[0].to(models.dtype)


@torch.no_grad()
def encode_text(models: DiffusionModels, texts: list[str]) -> Tensor:
    """text_states without gradients."""
    return text_states(models, texts)


def encode_view_text(models: DiffusionModels, unet: str, controlnet: str, negative: str) -> SDSText:
    """The three prompts of one view, encoded."""
    encoded = encode_text(models, [unet, controlnet, negative])
    return SDSText(encoded[0:1], encoded[1:2], encoded[2:3])


def add_noise(models: DiffusionModels, latents: Tensor, noise: Tensor, timesteps: Tensor | int) -> Tensor:
    """The forward diffusion: sqrt(alpha_bar_t) latents + sqrt(1 - alpha_bar_t) noise, per sample for a
    [B] tensor of timesteps."""
    alpha_bar = models.alphas_cumprod[timesteps].to(latents.dtype)
    if alpha_bar.dim() == 1:
        alpha_bar = alpha_bar[:, None, None, None]
    return alpha_bar.sqrt() * latents + (1.0 - alpha_bar).sqrt() * noise


def encode_images(models: DiffusionModels, rgb: Tensor) -> Tensor:
    """[B, 3, S, S] RGB in 0..1 -> [B, C, S/f, S/f] scaled latents (the posterior's mean: deterministic)."""
    posterior = models.vae.encode(rgb.to(models.dtype) * 2.0 - 1.0).latent_dist
    return posterior.mean * models.vae.config.scaling_factor


def predicted_noise(models: DiffusionModels, noisy: Tensor, timestep: int, skeleton: Tensor, text: SDSText,
                    config: SDSConfig) -> Tensor:
    """Guided noise prediction [B, C, h, w] for ``noisy`` latents at ``timestep``, ``skeleton [B, 3, S, S]``."""
    batch = noisy.shape[0]
    both = torch.cat([noisy, noisy])
    t = torch.full((2 * batch,), timestep, device=noisy.device, dtype=torch.long)
    control = torch.cat([skeleton, skeleton]).to(models.dtype)
    unet_text = torch.cat([text.unet.expand(batch, -1, -1), text.negative.expand(batch, -1, -1)])
    control_text = torch.cat([text.controlnet.expand(batch, -1, -1), text.negative.expand(batch, -1, -1)])
    down, middle = models.controlnet(both, t, encoder_hidden_states=control_text, controlnet_cond=control,
                                     conditioning_scale=config.controlnet_scale, return_dict=False)
    noise = models.unet(both, t, encoder_hidden_states=unet_text, down_block_additional_residuals=down,
                        mid_block_additional_residual=middle, return_dict=False)[0]
    conditional, negative = noise.chunk(2)
    return negative + config.guidance_scale * (conditional - negative)


@dataclass
class SDSInfo:
    """What one SDS step saw: the norm of its latent gradient, how many of its values were not finite (NaN
    or inf guidance, set to 0: those latents get no gradient; the prior reports them), and, when asked, the
    one-step denoised guess decoded to RGB ``preview [B, 3, S, S]`` in 0..1 (what the guidance pulls the
    render towards)."""

    grad_norm: float
    preview: Tensor | None = None
    nonfinite: int = 0


def denoised_latents(models: DiffusionModels, noisy: Tensor, predicted: Tensor, timestep: int) -> Tensor:
    """The one-step estimate of the clean latents, (noisy - sqrt(1 - alpha_bar_t) eps) / sqrt(alpha_bar_t)."""
    alpha_bar = models.alphas_cumprod[timestep].to(noisy.dtype)
    return (noisy - (1.0 - alpha_bar).sqrt() * predicted) / alpha_bar.sqrt()


@torch.no_grad()
def decode_latents(models: DiffusionModels, latents: Tensor) -> Tensor:
    """[B, C, h, w] scaled latents -> [B, 3, S, S] RGB in 0..1 (the VAE's decoder)."""
    images = models.vae.decode(latents / models.vae.config.scaling_factor, return_dict=False)[0]
    return ((images.float() + 1.0) / 2.0).clamp(0.0, 1.0)


def sds_loss(models: DiffusionModels, rgb: Tensor, skeleton: Tensor, text: SDSText, timestep: int,
             generator: torch.Generator, config: SDSConfig, preview: bool = False) -> tuple[Tensor, SDSInfo]:
    """The SDS loss of renders ``rgb [B, 3, H, W]`` (0..1, differentiable) against the skeleton images
    ``skeleton [B, 3, S, S]`` (0..1, S = config.resolution_px) at integer ``timestep``; its gradient in the
    latents is w(t) (eps_hat - eps). ``preview`` also decodes the denoised guess (one VAE decode)."""
    size = config.resolution_px
    if rgb.shape[-2:] != (size, size):
        rgb = F.interpolate(rgb, size=(size, size), mode="bilinear", align_corners=False)
    latents = encode_images(models, rgb.clamp(0.0, 1.0))
    noise = torch.randn(latents.shape, generator=generator, device=generator.device).to(latents)
    alpha_bar = models.alphas_cumprod[timestep].to(latents.dtype)
    with torch.no_grad():
        noisy = add_noise(models, latents, noise, timestep)
        guided = predicted_noise(models, noisy, timestep, skeleton, text, config)
        grad = (1.0 - alpha_bar) * (guided - noise)
        nonfinite = int((~torch.isfinite(grad)).sum())
        grad = torch.nan_to_num(grad, nan=0.0, posinf=0.0, neginf=0.0)
        target = latents - grad
        guess = decode_latents(models, denoised_latents(models, noisy, guided, timestep)) if preview else None
    loss = 0.5 * (latents.float() - target.float()).square().sum() / latents.shape[0]
    return loss, SDSInfo(float(grad.float().norm()), guess, nonfinite)
