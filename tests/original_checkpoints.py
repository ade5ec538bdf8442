"""The tiny diffusion models of tests/tiny_diffusion.py written as single-file checkpoints in the original
layouts (CompVis Stable Diffusion: ``model.diffusion_model.``, ``first_stage_model.``,
``cond_stage_model.transformer.``; lllyasviel's ControlNet: ``control_model.``), as users hold SD 1.5 and
ControlNet weights, with the small config folders that go with them.

The renaming here is the inverse of diffusers' conversion, written from the two layouts' naming rules;
tests check it by converting back with diffusers and comparing every weight.
"""

from __future__ import annotations

from pathlib import Path

import torch
from safetensors.torch import save_file
from torch import Tensor

from tests.tiny_diffusion import tiny_models

RESNET_NAMES = (("norm1", "in_layers.0"), ("conv1", "in_layers.2"), ("norm2", "out_layers.0"),
                ("conv2", "out_layers.3"), ("time_emb_proj", "emb_layers.1"), ("conv_shortcut", "skip_connection"))
VAE_ATTENTION_NAMES = (("group_norm", "norm"), ("to_q", "q"), ("to_k", "k"), ("to_v", "v"), ("to_out.0", "proj_out"))
UNET_FIXED = {"time_embedding.linear_1": "time_embed.0", "time_embedding.linear_2": "time_embed.2",
              "conv_in": "input_blocks.0.0", "conv_norm_out": "out.0", "conv_out": "out.2",
              "controlnet_cond_embedding.conv_in": "input_hint_block.0",
              "controlnet_cond_embedding.conv_out": "input_hint_block.14",
              "controlnet_mid_block": "middle_block_out.0"}
VAE_FIXED = {"encoder.conv_norm_out": "encoder.norm_out", "decoder.conv_norm_out": "decoder.norm_out"}


def _renamed(name: str, pairs) -> str:
    for new, old in pairs:
        name = name.replace(new, old)
    return name


def unet_original_name(name: str, layers: int, up_with_attention: set[int]) -> str:
    """The original (LDM) name of a diffusers UNet or ControlNet weight; ``layers`` per block."""
    module, _, leaf = name.rpartition(".")
    if module in UNET_FIXED:
        return f"{UNET_FIXED[module]}.{leaf}"
    parts = module.split(".")
    if parts[0] == "controlnet_down_blocks":
        return f"zero_convs.{parts[1]}.0.{leaf}"
    if parts[0] == "controlnet_cond_embedding":  # blocks.j -> input_hint_block.2(j + 1)
        return f"input_hint_block.{2 * (int(parts[2]) + 1)}.{leaf}"
    if parts[0] == "mid_block":
        rest = ".".join(parts[3:] + [leaf])
        return (f"middle_block.{2 * int(parts[2])}.{_renamed(rest, RESNET_NAMES)}" if parts[1] == "resnets"
                else f"middle_block.1.{rest}")
    level, kind = int(parts[1]), parts[2]
    if parts[0] == "down_blocks":
        if kind == "downsamplers":
            return f"input_blocks.{(level + 1) * (layers + 1)}.0.op.{leaf}"
        block = 1 + level * (layers + 1) + int(parts[3])
    else:
        if kind == "upsamplers":
            slot = 2 if level in up_with_attention else 1
            return f"output_blocks.{level * (layers + 1) + layers}.{slot}.conv.{leaf}"
        block = level * (layers + 1) + int(parts[3])
    rest = ".".join(parts[4:] + [leaf])
    prefix = "input_blocks" if parts[0] == "down_blocks" else "output_blocks"
    return (f"{prefix}.{block}.0.{_renamed(rest, RESNET_NAMES)}" if kind == "resnets"
            else f"{prefix}.{block}.1.{rest}")


def vae_original_name(name: str, levels: int) -> str:
    """The original name of a diffusers VAE weight; ``levels`` down (and up) blocks."""
    module, _, leaf = name.rpartition(".")
    if module in VAE_FIXED:
        return f"{VAE_FIXED[module]}.{leaf}"
    parts = module.split(".")
    if len(parts) < 3:
        return name
    coder, group = parts[0], parts[1]
    if group == "mid_block":
        if parts[2] == "resnets":
            rest = _renamed(".".join(parts[4:] + [leaf]), (("conv_shortcut", "nin_shortcut"),))
            return f"{coder}.mid.block_{int(parts[3]) + 1}.{rest}"
        return f"{coder}.mid.attn_1.{_renamed('.'.join(parts[4:] + [leaf]), VAE_ATTENTION_NAMES)}"
    level = int(parts[2]) if group == "down_blocks" else levels - 1 - int(parts[2])
    where = "down" if group == "down_blocks" else "up"
    if parts[3] in ("downsamplers", "upsamplers"):
        return f"{coder}.{where}.{level}.{where}sample.conv.{leaf}"
    rest = _renamed(".".join(parts[5:] + [leaf]), (("conv_shortcut", "nin_shortcut"),))
    return f"{coder}.{where}.{level}.block.{parts[4]}.{rest}"


def original_state(unet, vae, text_encoder) -> dict[str, Tensor]:
    """One Stable Diffusion checkpoint's tensors in the CompVis layout."""
    layers = unet.config.layers_per_block
    up_with_attention = {k for k, kind in enumerate(unet.config.up_block_types) if "CrossAttn" in kind}
    state = {f"model.diffusion_model.{unet_original_name(n, layers, up_with_attention)}": v
             for n, v in unet.state_dict().items()}
    levels = len(vae.config.down_block_types)
    for name, value in vae.state_dict().items():
        if ".mid_block.attentions." in name and value.ndim == 2:
            value = value[:, :, None, None]  # the original attention projections are 1x1 convolutions
        state[f"first_stage_model.{vae_original_name(name, levels)}"] = value
    for name, value in text_encoder.state_dict().items():
        state[f"cond_stage_model.transformer.text_model.{name}"] = value
    positions = text_encoder.config.max_position_embeddings
    state["cond_stage_model.transformer.text_model.embeddings.position_ids"] = torch.arange(positions)[None]
    return {name: value.contiguous() for name, value in state.items()}


def original_controlnet_state(controlnet) -> dict[str, Tensor]:
    """The ControlNet's tensors in lllyasviel's layout (``control_model.``)."""
    layers = controlnet.config.layers_per_block
    return {f"control_model.{unet_original_name(n, layers, set())}": v.contiguous()
            for n, v in controlnet.state_dict().items()}


def write_original_checkpoints(folder: Path, seed: int = 0) -> dict[str, Path]:
    """{"sd": .safetensors, "sd_configs": folder, "controlnet": .pth, "controlnet_configs": folder} for the tiny
    models of ``seed``; the ControlNet as a pickled {"state_dict": ...}, as .pth / .ckpt files hold it."""
    unet, controlnet, vae, text_encoder, tokenizer, scheduler = tiny_models(folder / "build", seed)
    sd_configs, controlnet_configs = folder / "sd_configs", folder / "controlnet_configs"
    unet.save_config(sd_configs / "unet")
    vae.save_config(sd_configs / "vae")
    text_encoder.config.save_pretrained(sd_configs / "text_encoder")
    tokenizer.save_pretrained(sd_configs / "tokenizer")
    scheduler.save_pretrained(sd_configs / "scheduler")
    controlnet.save_config(controlnet_configs)
    sd_file, controlnet_file = folder / "tiny-sd15.safetensors", folder / "tiny_openpose.pth"
    save_file(original_state(unet, vae, text_encoder), str(sd_file))
    torch.save({"state_dict": original_controlnet_state(controlnet)}, controlnet_file)
    return {"sd": sd_file, "sd_configs": sd_configs, "controlnet": controlnet_file,
            "controlnet_configs": controlnet_configs}
