"""Stage 05 with the sds prior: each person's CustomDiffusion identity from their crops.

A person's training set is their crops (stage 05's images over random colours, soft masks,
skeletons, view prompts) plus any reference photos the scene gives
(``humans/<pid>/reference/*.png``, paper supplementary "Enhancing identity"): a photo is cropped to
its centred square, resized to the crop size, counts as the person everywhere, has no skeleton (a
black condition) and the prompt ``reference_prompt``. After training, a grid of samples from the
personalised model (DDIM, the first crops' skeletons and prompts) shows what the identity learnt.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import torch

from glimpse.io.images import read_rgb, rgb_to_uint8, write_png
from glimpse.prior.sds.guidance import DiffusionModels, SDSConfig, decode_latents, encode_view_text, predicted_noise
from glimpse.prior.sds.identity import IDENTITY_FORMAT, IdentitySwitch, PersonIdentity, new_identity, save_identity
from glimpse.prior.sds.prompts import without_token
from glimpse.prior.sds.train_identity import IdentityConfig, IdentityExample, SampleConfig, train_identity
from glimpse.prior.views import person_token

COLOUR_LEVELS = 255.0
IDENTITY_FILE = "identity.safetensors"
SAMPLES_FILE = "samples.png"
LOSS_SUMMARY_FRACTION = 0.1  # the summary's first / last loss: means over this share of the steps
PERSON_SEED_STRIDE = 1_000_003  # person k of a run seeded s draws from seed s * stride + k

def unit_image(pixels: np.ndarray) -> torch.Tensor:
    """[H, W, 3] uint8 -> [3, H, W] float in 0..1."""
    return torch.as_tensor(pixels, dtype=torch.float32).permute(2, 0, 1) / COLOUR_LEVELS


def crop_examples(crops_dir: Path, doc: dict) -> list[IdentityExample]:
    """The training examples of one person's crops (``crops_dir`` holds images/, masks/, skeletons/ and
    ``doc`` is its crops.json)."""
    token = doc["token"]
    examples = []
    for entry in doc["crops"]:
        name = entry["file"]
        mask = read_rgb(crops_dir / "masks" / name)[..., 0].astype(np.float32) / COLOUR_LEVELS
        examples.append(IdentityExample(unit_image(read_rgb(crops_dir / "images" / name)), torch.as_tensor(mask),
                                        unit_image(read_rgb(crops_dir / "skeletons" / name)), entry["prompt"],
                                        without_token(entry["prompt"], token)))
    return examples


def reference_examples(paths: list[Path], pid: str, size: int, prompt_template: str) -> list[IdentityExample]:
    """Examples from reference photos: centred square crop, ``size`` pixels, mask everywhere, no skeleton;
    ``prompt_template`` with {token}."""
    token = person_token(pid)
    prompt = prompt_template.format(token=token)
    examples = []
    for path in paths:
        image = read_rgb(path)
        height, width = image.shape[:2]
        side = min(height, width)
        top, left = (height - side) // 2, (width - side) // 2
        square = cv2.resize(image[top:top + side, left:left + side], (size, size), interpolation=cv2.INTER_AREA)
        examples.append(IdentityExample(unit_image(square), torch.ones(size, size), torch.zeros(3, size, size), prompt,
                                        without_token(prompt, token)))
    return examples


@torch.no_grad()
def sample_grid(models: DiffusionModels, identity: PersonIdentity, examples: list[IdentityExample],
                config: SampleConfig, controlnet_scale: float, seed: int) -> np.ndarray:
    """[S, K S, 3] uint8: K = min(count, examples) samples of the personalised model, each from an example's
    skeleton and prompt (DDIM, ``config.steps`` steps, guidance ``config.guidance_scale``)."""
    from diffusers import DDIMScheduler

    chosen = examples[: config.count]
    size = chosen[0].skeleton.shape[-1]
    scheduler = DDIMScheduler.from_config(models.scheduler.config)
    scheduler.set_timesteps(config.steps, device=models.device)
    switch = IdentitySwitch(models.unet)
    switch.use(identity)
    guidance = SDSConfig(config.guidance_scale, controlnet_scale, size)
    generator = torch.Generator().manual_seed(seed)
    tiles = []
    try:
        for example in chosen:
            text = encode_view_text(models, example.prompt, example.control_prompt, "")
            shape = (1, models.unet.config.in_channels, size // models.vae_scale_factor, size // models.vae_scale_factor)
            latents = torch.randn(shape, generator=generator).to(models.device, models.dtype)
            skeleton = example.skeleton[None].to(models.device, models.dtype)
            for timestep in scheduler.timesteps:
                noise = predicted_noise(models, latents, int(timestep), skeleton, text, guidance)
                latents = scheduler.step(noise, timestep, latents).prev_sample
            image = decode_latents(models, latents)[0]
            tiles.append(rgb_to_uint8(image.permute(1, 2, 0)))
    finally:
        switch.use(None)
    return np.concatenate(tiles, axis=1)


def train_person_identity(models: DiffusionModels, pid: str, crops_dir: Path, doc: dict, references: list[Path],
                          config: IdentityConfig, seed: int, out: Path) -> dict:
    """Train, save (``out/identity.safetensors``) and sample (``out/samples.png``) one person's identity;
    returns its summary for the manifest."""
    examples = crop_examples(crops_dir, doc)
    examples += reference_examples(references, pid, doc["crop_size_px"], config.reference_prompt)
    if not examples:
        return {"trained": False, "note": "no crops and no reference photos: nothing to learn the identity from"}
    identity = new_identity(models, doc["token"])
    losses = train_identity(models, identity, examples, config, torch.Generator().manual_seed(seed))
    save_identity(identity, models, out / IDENTITY_FILE)
    if config.samples.count > 0:
        write_png(out / SAMPLES_FILE, sample_grid(models, identity, examples, config.samples, config.controlnet_scale,
                                                  seed))
    share = max(int(len(losses) * LOSS_SUMMARY_FRACTION), 1)
    return {"trained": True, "token": doc["token"], "examples": len(examples), "references": len(references),
            "steps": len(losses), "loss_first": float(np.mean(losses[:share])) if losses else None,
            "loss_last": float(np.mean(losses[-share:])) if losses else None}


def train_identities(models: DiffusionModels, docs: dict[str, dict], references: dict[str, list[Path]],
                     config: IdentityConfig, seed: int, out: Path) -> dict[str, dict]:
    """Every person's identity under ``out/<pid>/identity/`` from ``out/<pid>/crops/`` (``docs``: pid ->
    crops.json) and their reference photos; pid -> summary. Each person has their own random stream."""
    summaries = {}
    for index, pid in enumerate(sorted(docs)):
        summaries[pid] = train_person_identity(models, pid, out / pid / "crops", docs[pid], references.get(pid, []),
                                               config, seed * PERSON_SEED_STRIDE + index, out / pid / "identity")
    return summaries


def identity_formats(out: Path, pids: list[str]) -> dict[str, str]:
    """The manifest's format entries of the identity files written under ``out``."""
    formats = {}
    for pid in pids:
        if (out / pid / "identity" / IDENTITY_FILE).is_file():
            formats[f"{pid}/identity/{IDENTITY_FILE}"] = IDENTITY_FORMAT
        if (out / pid / "identity" / SAMPLES_FILE).is_file():
            formats[f"{pid}/identity/{SAMPLES_FILE}"] = "png (RGB)"
    return formats
