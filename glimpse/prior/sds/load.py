"""Loading the diffusion prior's weights from the local folders pipeline.yaml names, never from a hub.

``diffusion.sd_path`` is a diffusers-format Stable Diffusion 1.5 folder (unet/, vae/, text_encoder/,
tokenizer/, scheduler/, as ``save_pretrained`` or a hub snapshot writes it); ``diffusion.controlnet_path``
a diffusers-format ControlNet folder (config.json and its weights). The hub is switched off for the
whole load (HF_HUB_OFFLINE, local_files_only), so a missing file is an error naming it instead of a
download. A single-file checkpoint (.safetensors / .ckpt) needs the hub's configs to be read: convert it
to a diffusers folder first (docs/diffusion.md says how).

SDS at SD 1.5's size needs CUDA: on a machine without it loading stops with a message, unless
``diffusion.allow_cpu`` (how the tests run tiny models). On CUDA the weights are fp16 when
``diffusion.half_precision``; attention uses PyTorch's scaled-dot-product kernels (diffusers' default).
"""

from __future__ import annotations

import os
from contextlib import contextmanager
from pathlib import Path

import torch

from glimpse.errors import ConfigError, GlimpseError
from glimpse.prior.sds.config import DiffusionConfig
from glimpse.prior.sds.guidance import DiffusionModels

SD_SUBFOLDERS = ("unet", "vae", "text_encoder", "tokenizer", "scheduler")
SINGLE_FILE_SUFFIXES = (".safetensors", ".ckpt", ".bin", ".pt")
OFFLINE_VARIABLES = ("HF_HUB_OFFLINE", "TRANSFORMERS_OFFLINE", "DIFFUSERS_OFFLINE")


def check_weight_paths(config: DiffusionConfig) -> tuple[Path, Path]:
    """The two weight folders, or a ConfigError saying which parameter to set and what it must hold."""
    given = {"diffusion.sd_path": config.sd_path, "diffusion.controlnet_path": config.controlnet_path}
    missing = [name for name, value in given.items() if not value]
    if missing:
        raise ConfigError(
            f"prior.kind sds needs the diffusion weights: set {' and '.join(missing)} in pipeline.yaml or with "
            "PARAMS (local diffusers-format folders: Stable Diffusion 1.5 and an OpenPose ControlNet for it; "
            "nothing is downloaded; docs/diffusion.md says where to get them)")
    sd, controlnet = Path(str(config.sd_path)).expanduser(), Path(str(config.controlnet_path)).expanduser()
    for name, path in (("diffusion.sd_path", sd), ("diffusion.controlnet_path", controlnet)):
        if path.is_file() and path.suffix in SINGLE_FILE_SUFFIXES:
            raise ConfigError(f"{name}: {path} is a single-file checkpoint; give a diffusers-format folder "
                              "(convert it once with diffusers' conversion script, docs/diffusion.md)")
        if not path.is_dir():
            raise ConfigError(f"{name}: {path} is not a folder")
    absent = [sub for sub in SD_SUBFOLDERS if not (sd / sub).is_dir()]
    if absent:
        raise ConfigError(f"diffusion.sd_path: {sd} lacks {', '.join(s + '/' for s in absent)} (a diffusers-format "
                          "Stable Diffusion folder has unet/, vae/, text_encoder/, tokenizer/ and scheduler/)")
    if not (controlnet / "config.json").is_file():
        raise ConfigError(f"diffusion.controlnet_path: {controlnet} has no config.json (a diffusers-format "
                          "ControlNet folder)")
    return sd, controlnet


def diffusion_ready(config: DiffusionConfig, device: torch.device) -> bool:
    """Whether ``prior.kind: auto`` picks sds: both weight paths set and a CUDA device (CONTRACTS.md)."""
    return bool(config.sd_path and config.controlnet_path) and device.type == "cuda"


def diffusion_device(config: DiffusionConfig, device: torch.device) -> tuple[torch.device, torch.dtype]:
    """Where and in what precision SDS runs: CUDA (fp16 when half_precision), or the CPU in fp32 only when
    allow_cpu; otherwise a GlimpseError."""
    if device.type == "cuda":
        return device, torch.float16 if config.half_precision else torch.float32
    if not config.allow_cpu:
        raise GlimpseError("prior.kind sds runs Stable Diffusion at every iteration and needs a CUDA GPU; none is "
                           "available here. Use prior.kind surface (no weights, CPU), or set diffusion.allow_cpu=true "
                           "to run it on the CPU anyway (hours per person at SD 1.5's size)")
    return device, torch.float32


@contextmanager
def hub_offline():
    """The hub switched off for diffusers and transformers while loading (restored after)."""
    saved = {name: os.environ.get(name) for name in OFFLINE_VARIABLES}
    os.environ.update({name: "1" for name in OFFLINE_VARIABLES})
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def load_diffusion(config: DiffusionConfig, device: torch.device) -> DiffusionModels:
    """The shared SD + ControlNet parts from the configured folders, frozen, on ``device``."""
    sd, controlnet_dir = check_weight_paths(config)
    device, dtype = diffusion_device(config, device)
    from diffusers import AutoencoderKL, ControlNetModel, DDPMScheduler, UNet2DConditionModel
    from transformers import CLIPTextModel, CLIPTokenizer

    with hub_offline():
        try:
            options = {"local_files_only": True, "torch_dtype": dtype}
            plain = {**options, "low_cpu_mem_usage": False}  # (true needs the accelerate package)
            unet = UNet2DConditionModel.from_pretrained(sd, subfolder="unet", **plain)
            vae = AutoencoderKL.from_pretrained(sd, subfolder="vae", **plain)
            text_encoder = CLIPTextModel.from_pretrained(sd, subfolder="text_encoder", **options)
            tokenizer = CLIPTokenizer.from_pretrained(sd, subfolder="tokenizer", local_files_only=True)
            scheduler = DDPMScheduler.from_pretrained(sd, subfolder="scheduler", local_files_only=True)
            controlnet = ControlNetModel.from_pretrained(controlnet_dir, **plain)
        except (OSError, ValueError) as error:
            raise GlimpseError(f"diffusion weights could not be read from {sd} and {controlnet_dir}: {error}") from error
    for module in (unet, vae, text_encoder, controlnet):
        module.to(device).eval().requires_grad_(False)
    return DiffusionModels(unet, controlnet, vae, text_encoder, tokenizer, scheduler, device)
