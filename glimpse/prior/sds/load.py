"""Loading the diffusion prior's weights from the local paths pipeline.yaml names, never from a hub.

``diffusion.sd_path`` is a diffusers-format Stable Diffusion 1.5 folder (unet/, vae/, text_encoder/,
tokenizer/, scheduler/, as ``save_pretrained`` or a hub snapshot writes it); ``diffusion.controlnet_path``
a diffusers-format ControlNet folder (config.json and its weights). Either may instead be a single-file
checkpoint (.safetensors / .ckpt / .pth, the original layouts) when the configs it lacks are given as local
folders: ``diffusion.sd_config_path`` and ``diffusion.controlnet_config_path`` (single_file.py). The hub is
switched off for the whole load (HF_HUB_OFFLINE, local_files_only), so a missing file is an error naming
it instead of a download.

SDS at SD 1.5's size needs CUDA: on a machine without it loading stops with a message, unless
``diffusion.allow_cpu`` (how the tests run tiny models). On CUDA the weights are fp16 when
``diffusion.half_precision``; attention uses PyTorch's scaled-dot-product kernels (diffusers' default).
"""

from __future__ import annotations

import os
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import torch

from glimpse.errors import ConfigError, GlimpseError
from glimpse.prior.sds.config import DiffusionConfig
from glimpse.prior.sds.guidance import DiffusionModels
from glimpse.prior.sds.single_file import controlnet_from_file, stable_diffusion_from_file

SD_SUBFOLDERS = ("unet", "vae", "text_encoder", "tokenizer", "scheduler")
SINGLE_FILE_SUFFIXES = (".safetensors", ".ckpt", ".pth", ".pt", ".bin")
OFFLINE_VARIABLES = ("HF_HUB_OFFLINE", "TRANSFORMERS_OFFLINE", "DIFFUSERS_OFFLINE")


@dataclass(frozen=True)
class WeightSources:
    """Where each part's weights are: a diffusers folder (``*_configs`` None) or a single file read against
    the diffusers config folder ``*_configs``."""

    sd: Path
    sd_configs: Path | None
    controlnet: Path
    controlnet_configs: Path | None


def _single_file(path: Path) -> bool:
    return path.is_file() and path.suffix in SINGLE_FILE_SUFFIXES


def _check_sd_folder(name: str, folder: Path) -> None:
    absent = [sub for sub in SD_SUBFOLDERS if not (folder / sub).is_dir()]
    if absent:
        raise ConfigError(f"{name}: {folder} lacks {', '.join(s + '/' for s in absent)} (a diffusers-format "
                          "Stable Diffusion folder has unet/, vae/, text_encoder/, tokenizer/ and scheduler/)")


def _check_controlnet_folder(name: str, folder: Path) -> None:
    if not (folder / "config.json").is_file():
        raise ConfigError(f"{name}: {folder} has no config.json (a diffusers-format ControlNet folder)")


def _configs_for(name: str, path: Path, config_name: str, given: str | None) -> Path:
    """The config folder a single-file checkpoint at ``path`` is read against, or a ConfigError."""
    if not given:
        raise ConfigError(f"{name}: {path} is a single-file checkpoint; it holds weights only, so set "
                          f"{config_name} to a local folder with its diffusers configs (nothing is downloaded; "
                          "docs/diffusion.md says which files), or give a diffusers-format folder instead")
    folder = Path(str(given)).expanduser()
    if not folder.is_dir():
        raise ConfigError(f"{config_name}: {folder} is not a folder")
    return folder


def check_weight_paths(config: DiffusionConfig) -> WeightSources:
    """Where the weights are, or a ConfigError saying which parameter to set and what it must hold."""
    given = {"diffusion.sd_path": config.sd_path, "diffusion.controlnet_path": config.controlnet_path}
    missing = [name for name, value in given.items() if not value]
    if missing:
        raise ConfigError(
            f"prior.kind sds needs the diffusion weights: set {' and '.join(missing)} in pipeline.yaml or with "
            "PARAMS (local diffusers-format folders, or single-file checkpoints with their configs: Stable "
            "Diffusion 1.5 and an OpenPose ControlNet for it; nothing is downloaded; docs/diffusion.md says "
            "where to get them)")
    sd, controlnet = Path(str(config.sd_path)).expanduser(), Path(str(config.controlnet_path)).expanduser()
    for name, path in (("diffusion.sd_path", sd), ("diffusion.controlnet_path", controlnet)):
        if not (path.is_dir() or _single_file(path)):
            raise ConfigError(f"{name}: {path} is neither a folder nor a single-file checkpoint "
                              f"({', '.join(SINGLE_FILE_SUFFIXES)})")
    sd_configs = controlnet_configs = None
    if _single_file(sd):
        sd_configs = _configs_for("diffusion.sd_path", sd, "diffusion.sd_config_path", config.sd_config_path)
        _check_sd_folder("diffusion.sd_config_path", sd_configs)
    else:
        _check_sd_folder("diffusion.sd_path", sd)
    if _single_file(controlnet):
        controlnet_configs = _configs_for("diffusion.controlnet_path", controlnet, "diffusion.controlnet_config_path",
                                          config.controlnet_config_path)
        _check_controlnet_folder("diffusion.controlnet_config_path", controlnet_configs)
    else:
        _check_controlnet_folder("diffusion.controlnet_path", controlnet)
    return WeightSources(sd, sd_configs, controlnet, controlnet_configs)


def check_sds_can_run(config: DiffusionConfig, device: torch.device) -> None:
    """Before any work (stages 05 and 06 with prior.kind sds): the weights are where pipeline.yaml says and SDS
    may run on ``device``; else the ConfigError or GlimpseError saying what to set."""
    check_weight_paths(config)
    diffusion_device(config, device)


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
    """The shared SD + ControlNet parts from the configured paths, frozen, on ``device``."""
    sources = check_weight_paths(config)
    device, dtype = diffusion_device(config, device)
    with hub_offline():
        try:
            if sources.sd_configs is None:
                unet, vae, text_encoder, tokenizer, scheduler = _stable_diffusion_from_folder(sources.sd, dtype)
            else:
                unet, vae, text_encoder, tokenizer, scheduler = stable_diffusion_from_file(
                    sources.sd, sources.sd_configs, dtype)
            if sources.controlnet_configs is None:
                controlnet = _controlnet_from_folder(sources.controlnet, dtype)
            else:
                controlnet = controlnet_from_file(sources.controlnet, sources.controlnet_configs, dtype)
        except (OSError, ValueError) as error:
            raise GlimpseError(f"diffusion weights could not be read from {sources.sd} and {sources.controlnet}: "
                               f"{error}") from error
    for module in (unet, vae, text_encoder, controlnet):
        module.to(device).eval().requires_grad_(False)
    return DiffusionModels(unet, controlnet, vae, text_encoder, tokenizer, scheduler, device)


def _stable_diffusion_from_folder(folder: Path, dtype: torch.dtype) -> tuple:
    """(unet, vae, text_encoder, tokenizer, scheduler) from a diffusers-format folder."""
    from diffusers import AutoencoderKL, DDPMScheduler, UNet2DConditionModel
    from transformers import CLIPTextModel, CLIPTokenizer

    options = {"local_files_only": True, "torch_dtype": dtype}
    plain = {**options, "low_cpu_mem_usage": False}  # (true needs the accelerate package)
    return (UNet2DConditionModel.from_pretrained(folder, subfolder="unet", **plain),
            AutoencoderKL.from_pretrained(folder, subfolder="vae", **plain),
            CLIPTextModel.from_pretrained(folder, subfolder="text_encoder", **options),
            CLIPTokenizer.from_pretrained(folder, subfolder="tokenizer", local_files_only=True),
            DDPMScheduler.from_pretrained(folder, subfolder="scheduler", local_files_only=True))


def _controlnet_from_folder(folder: Path, dtype: torch.dtype):
    from diffusers import ControlNetModel

    return ControlNetModel.from_pretrained(folder, local_files_only=True, torch_dtype=dtype, low_cpu_mem_usage=False)
