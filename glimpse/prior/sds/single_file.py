"""Reading single-file checkpoints (``.safetensors``, ``.ckpt``, ``.pth``: the original Stable Diffusion and
ControlNet layouts) with configs the user gives locally, never the hub's.

A single file holds weights only; the models' shapes come from a diffusers-format config folder:
``diffusion.sd_config_path`` (the small files of an SD 1.5 snapshot: ``unet/config.json``,
``vae/config.json``, ``text_encoder/config.json``, ``tokenizer/``, ``scheduler/``) and
``diffusion.controlnet_config_path`` (a folder with the ControlNet's ``config.json``). The weights are
renamed into diffusers' layout by diffusers' own conversion functions, then loaded strictly: a weight the
configs expect and the file lacks, one the file has and the configs do not, or a shape that differs
stops the load with the file named (diffusers' ``from_single_file`` would leave such weights random).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import torch
from torch import Tensor, nn

from glimpse.errors import GlimpseError

CLIP_PREFIX = "cond_stage_model.transformer."  # SD 1.x: the HF CLIP text model under this prefix
CLIP_WRAPPER = "text_model."  # transformers < 5.6 nested CLIPTextModel's weights under this name
EXAMPLES_SHOWN = 3


def read_checkpoint(path: Path) -> dict[str, Tensor]:
    """All tensors of a single-file checkpoint (a nested ``state_dict`` unwrapped), read locally."""
    from diffusers.loaders.single_file_utils import load_single_file_checkpoint

    try:
        return dict(load_single_file_checkpoint(str(path), local_files_only=True))
    except Exception as error:  # unreadable pickles and safetensors raise many kinds
        raise GlimpseError(f"{path}: not a readable checkpoint ({type(error).__name__}: {error})") from error


def load_exactly(model: nn.Module, weights: Mapping[str, Tensor], what: str, path: Path, config_dir: Path) -> None:
    """``weights`` into ``model``, every one of its weights and nothing else; else a GlimpseError naming
    ``path`` (the checkpoint) and ``config_dir`` (the configs it was read against)."""
    expected = model.state_dict()
    unsaved_buffers = {name for name, _ in model.named_buffers()} - set(expected)  # e.g. CLIP's position_ids
    weights = {name: value for name, value in weights.items() if name not in unsaved_buffers}
    missing = sorted(set(expected) - set(weights))
    extra = sorted(set(weights) - set(expected))
    reshaped = sorted(name for name in set(expected) & set(weights) if expected[name].shape != weights[name].shape)
    problems = [f"{len(names)} {kind} (e.g. {', '.join(names[:EXAMPLES_SHOWN])})"
                for kind, names in (("missing", missing), ("unexpected", extra), ("of another shape", reshaped))
                if names]
    if problems:
        raise GlimpseError(f"{path}: its {what} does not fit the configs in {config_dir}: weights "
                           f"{'; '.join(problems)}. Is it a Stable Diffusion 1.5 checkpoint (and an SD 1.5 "
                           "ControlNet) matching those configs?")
    model.load_state_dict(weights, strict=True)


def clip_weights(checkpoint: Mapping[str, Tensor], model: nn.Module) -> dict[str, Tensor]:
    """The text encoder's weights of an SD 1.x checkpoint, named as ``model`` (a CLIPTextModel) names them."""
    weights = {name[len(CLIP_PREFIX):]: value for name, value in checkpoint.items() if name.startswith(CLIP_PREFIX)}
    if not any(name.startswith(CLIP_WRAPPER) for name in model.state_dict()):
        weights = {name.removeprefix(CLIP_WRAPPER): value for name, value in weights.items()}
    return weights


def stable_diffusion_from_file(path: Path, config_dir: Path, dtype: torch.dtype) -> tuple:
    """(unet, vae, text_encoder, tokenizer, scheduler) from the single file ``path`` and the diffusers
    config folder ``config_dir``."""
    from diffusers import AutoencoderKL, DDPMScheduler, UNet2DConditionModel
    from diffusers.loaders.single_file_utils import convert_ldm_unet_checkpoint, convert_ldm_vae_checkpoint
    from transformers import CLIPTextConfig, CLIPTextModel, CLIPTokenizer

    checkpoint = read_checkpoint(path)
    local = {"local_files_only": True}
    unet = UNet2DConditionModel.from_config(UNet2DConditionModel.load_config(config_dir, subfolder="unet", **local))
    load_exactly(unet, convert_ldm_unet_checkpoint(checkpoint, unet.config), "UNet", path, config_dir)
    vae = AutoencoderKL.from_config(AutoencoderKL.load_config(config_dir, subfolder="vae", **local))
    load_exactly(vae, convert_ldm_vae_checkpoint(checkpoint, vae.config), "VAE", path, config_dir)
    text_encoder = CLIPTextModel(CLIPTextConfig.from_pretrained(config_dir, subfolder="text_encoder", **local))
    load_exactly(text_encoder, clip_weights(checkpoint, text_encoder), "text encoder", path, config_dir)
    tokenizer = CLIPTokenizer.from_pretrained(config_dir, subfolder="tokenizer", **local)
    scheduler = DDPMScheduler.from_pretrained(config_dir, subfolder="scheduler", **local)
    return unet.to(dtype), vae.to(dtype), text_encoder.to(dtype), tokenizer, scheduler


def controlnet_from_file(path: Path, config_dir: Path, dtype: torch.dtype):
    """The ControlNet from the single file ``path`` and the folder ``config_dir`` holding its config.json."""
    from diffusers import ControlNetModel
    from diffusers.loaders.single_file_utils import convert_controlnet_checkpoint

    controlnet = ControlNetModel.from_config(ControlNetModel.load_config(config_dir, local_files_only=True))
    load_exactly(controlnet, convert_controlnet_checkpoint(read_checkpoint(path), controlnet.config), "ControlNet",
                 path, config_dir)
    return controlnet.to(dtype)
