"""Tiny random Stable Diffusion parts for tests: the same diffusers / transformers classes as SD 1.5 with
an OpenPose ControlNet, built from small configs (no weights are downloaded), and a byte-level CLIP
tokenizer with no merges. Renders of RENDER_PX pixels map to latents of RENDER_PX / 8 (SD's VAE factor)."""

from __future__ import annotations

import json
from pathlib import Path

import torch

RENDER_PX = 64  # the tiny models' resolution (SD 1.5: 512)
TEXT_DIM = 32
MAX_TOKENS = 16


def _byte_alphabet() -> list[str]:
    """CLIP's printable stand-ins for the 256 byte values (its bytes_to_unicode order)."""
    kept = (list(range(ord("!"), ord("~") + 1)) + list(range(ord("¡"), ord("¬") + 1))
            + list(range(ord("®"), ord("ÿ") + 1)))
    codes, extra = kept[:], 0
    for byte in range(256):
        if byte not in kept:
            codes.append(256 + extra)
            extra += 1
    return [chr(c) for c in codes]


def write_tokenizer(folder: Path) -> Path:
    """A CLIP tokenizer folder (vocab.json, merges.txt) with one token per byte and no merges."""
    folder.mkdir(parents=True, exist_ok=True)
    chars = _byte_alphabet()
    vocab = chars + [c + "</w>" for c in chars] + ["<|startoftext|>", "<|endoftext|>"]
    (folder / "vocab.json").write_text(json.dumps({token: i for i, token in enumerate(vocab)}))
    (folder / "merges.txt").write_text("#version: 0.2\n")
    return folder


def tiny_models(folder: Path, seed: int = 0):
    """(unet, controlnet, vae, text_encoder, tokenizer, scheduler), random weights from ``seed``."""
    from diffusers import AutoencoderKL, ControlNetModel, DDPMScheduler, UNet2DConditionModel
    from transformers import CLIPTextConfig, CLIPTextModel, CLIPTokenizer

    torch.manual_seed(seed)
    unet = UNet2DConditionModel(
        sample_size=RENDER_PX // 8, in_channels=4, out_channels=4, layers_per_block=1,
        block_out_channels=(16, 32), down_block_types=("CrossAttnDownBlock2D", "DownBlock2D"),
        up_block_types=("UpBlock2D", "CrossAttnUpBlock2D"), cross_attention_dim=TEXT_DIM, attention_head_dim=4,
        norm_num_groups=8)
    controlnet = ControlNetModel.from_unet(unet, conditioning_embedding_out_channels=(8, 8, 8, 16))
    vae = AutoencoderKL(in_channels=3, out_channels=3, latent_channels=4, block_out_channels=(8, 8, 16, 16),
                        down_block_types=("DownEncoderBlock2D",) * 4, up_block_types=("UpDecoderBlock2D",) * 4,
                        layers_per_block=1, norm_num_groups=4, sample_size=RENDER_PX)
    text_encoder = CLIPTextModel(CLIPTextConfig(
        vocab_size=514, hidden_size=TEXT_DIM, intermediate_size=37, num_attention_heads=4, num_hidden_layers=2,
        max_position_embeddings=MAX_TOKENS, bos_token_id=512, eos_token_id=513, pad_token_id=513))
    tokenizer_dir = write_tokenizer(folder / "tokenizer")
    tokenizer = CLIPTokenizer(str(tokenizer_dir / "vocab.json"), str(tokenizer_dir / "merges.txt"),
                              model_max_length=MAX_TOKENS)
    scheduler = DDPMScheduler(num_train_timesteps=1000, beta_start=0.00085, beta_end=0.012,
                              beta_schedule="scaled_linear")
    for module in (unet, controlnet, vae, text_encoder):
        module.eval().requires_grad_(False)
    return unet, controlnet, vae, text_encoder, tokenizer, scheduler


def write_tiny_weights(folder: Path, seed: int = 0) -> tuple[Path, Path]:
    """(sd_path, controlnet_path): the tiny models saved as diffusers-format folders, as a user's would be."""
    unet, controlnet, vae, text_encoder, tokenizer, scheduler = tiny_models(folder / "build", seed)
    sd, controlnet_dir = folder / "sd", folder / "controlnet"
    unet.save_pretrained(sd / "unet")
    vae.save_pretrained(sd / "vae")
    text_encoder.save_pretrained(sd / "text_encoder")
    tokenizer.save_pretrained(sd / "tokenizer")
    scheduler.save_pretrained(sd / "scheduler")
    controlnet.save_pretrained(controlnet_dir)
    return sd, controlnet_dir
