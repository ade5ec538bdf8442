"""One SDS step at Stable Diffusion 1.5's size: time and peak memory (the diffusion prior's cost).

The models are diffusers / transformers classes built from SD 1.5's and its OpenPose ControlNet's
configs with random weights (no download): the cost of a step does not depend on the weights. A step
is glimpse.prior.sds.guidance.sds_loss on a differentiable render of ``--size`` pixels resized to
512 (VAE encode with gradients, ControlNet + UNet with classifier-free guidance, the latent
gradient) plus its backward pass to the render. The baseline, timed in the same run, is the guided
noise prediction alone (ControlNet + UNet on a batch of two, no VAE, no gradients).

On CUDA: fp16, 512², 5 timed steps after 2 warm-up ones; on a CPU (default there: --quick, 256²
renders resized to 256, 1 step) the numbers only show the script works; ``--full`` runs 512² there too
(fp32, one step, minutes). A second table gives each part's parameters and weight memory in the run's
precision (the CLIP text encoder too, built from SD 1.5's config), which hold on any device.

    .venv/bin/python bench/sds.py [--quick | --full] [--size 512] [--device cuda]
"""

from __future__ import annotations

import argparse
import resource
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench._timing import median_seconds, no_sync  # noqa: E402
from glimpse.prior.sds.guidance import DiffusionModels, SDSConfig, SDSText, predicted_noise, sds_loss  # noqa: E402

SD15_UNET = dict(sample_size=64, in_channels=4, out_channels=4, layers_per_block=2,
                 block_out_channels=(320, 640, 1280, 1280),
                 down_block_types=("CrossAttnDownBlock2D", "CrossAttnDownBlock2D", "CrossAttnDownBlock2D",
                                   "DownBlock2D"),
                 up_block_types=("UpBlock2D", "CrossAttnUpBlock2D", "CrossAttnUpBlock2D", "CrossAttnUpBlock2D"),
                 cross_attention_dim=768, attention_head_dim=8)
SD15_VAE = dict(in_channels=3, out_channels=3, latent_channels=4, block_out_channels=(128, 256, 512, 512),
                down_block_types=("DownEncoderBlock2D",) * 4, up_block_types=("UpDecoderBlock2D",) * 4,
                layers_per_block=2, sample_size=512)
TEXT_TOKENS, TEXT_DIM = 77, 768
SD15_TEXT_ENCODER = dict(vocab_size=49408, hidden_size=TEXT_DIM, intermediate_size=3072, num_attention_heads=12,
                         num_hidden_layers=12, max_position_embeddings=TEXT_TOKENS)
GUIDANCE, CONTROLNET_SCALE, TIMESTEP = 50.0, 0.7, 500
CPU_THREADS = 2


class _NoTokenizer:
    model_max_length = TEXT_TOKENS


def build(device: torch.device, dtype: torch.dtype) -> DiffusionModels:
    from diffusers import AutoencoderKL, ControlNetModel, DDPMScheduler, UNet2DConditionModel
    from transformers import CLIPTextConfig, CLIPTextModel

    torch.manual_seed(0)
    unet = UNet2DConditionModel(**SD15_UNET)
    controlnet = ControlNetModel.from_unet(unet)
    vae = AutoencoderKL(**SD15_VAE)
    text_encoder = CLIPTextModel(CLIPTextConfig(**SD15_TEXT_ENCODER))
    scheduler = DDPMScheduler(num_train_timesteps=1000, beta_start=0.00085, beta_end=0.012,
                              beta_schedule="scaled_linear")
    for module in (unet, controlnet, vae, text_encoder):
        module.to(device, dtype).eval().requires_grad_(False)
    return DiffusionModels(unet, controlnet, vae, text_encoder, _NoTokenizer(), scheduler, device)


def print_weights(models: DiffusionModels) -> None:
    """Each part's parameter count and weight memory (MB, in the parts' precision)."""
    parts = {"UNet": models.unet, "ControlNet": models.controlnet, "VAE": models.vae,
             "CLIP text encoder": models.text_encoder}
    print("\n| part | parameters (M) | weights MB |\n|---|---:|---:|")
    total_count = total_bytes = 0
    for name, module in parts.items():
        count = sum(p.numel() for p in module.parameters())
        size = sum(p.numel() * p.element_size() for p in module.parameters())
        total_count, total_bytes = total_count + count, total_bytes + size
        print(f"| {name} | {count / 1e6:.1f} | {size / 2**20:.0f} |")
    print(f"| all | {total_count / 1e6:.1f} | {total_bytes / 2**20:.0f} |")


def peak_mb(device: torch.device) -> float:
    if device.type == "cuda":
        return torch.cuda.max_memory_allocated(device) / 2**20
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--quick", action="store_true", help="256² renders and diffusion resolution, one step")
    parser.add_argument("--full", action="store_true", help="512² on a CPU too (one step, fp32, minutes)")
    parser.add_argument("--size", type=int, default=512, help="render side, pixels (resized to the resolution)")
    args = parser.parse_args()
    device = torch.device(args.device)
    quick = args.quick or (device.type == "cpu" and not args.full)
    dtype = torch.float16 if device.type == "cuda" else torch.float32
    resolution = 256 if quick else 512
    size = min(args.size, resolution) if quick else args.size
    warmup, repeats = (0, 1) if quick or device.type == "cpu" else (2, 5)
    if device.type == "cpu":
        torch.set_num_threads(CPU_THREADS)
    models = build(device, dtype)
    text = SDSText(*(torch.randn(1, TEXT_TOKENS, TEXT_DIM, device=device, dtype=dtype) for _ in range(3)))
    config = SDSConfig(GUIDANCE, CONTROLNET_SCALE, resolution)
    skeleton = torch.rand(1, 3, resolution, resolution, device=device)
    render = torch.rand(1, 3, size, size, device=device, requires_grad=True)
    latent = resolution // models.vae_scale_factor
    noisy = torch.randn(1, 4, latent, latent, device=device, dtype=dtype)
    generator = torch.Generator(device=device).manual_seed(0)

    def baseline():
        with torch.no_grad():
            predicted_noise(models, noisy, TIMESTEP, skeleton, text, config)

    def step():
        loss, _ = sds_loss(models, render, skeleton, text, TIMESTEP, generator, config)
        loss.backward()
        render.grad = None

    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    before = peak_mb(device)
    sync = (lambda: torch.cuda.synchronize(device)) if device.type == "cuda" else no_sync
    base_s = median_seconds(baseline, repeats, warmup, sync)
    step_s = median_seconds(step, repeats, warmup, sync)
    machine = torch.cuda.get_device_name(device) if device.type == "cuda" else f"CPU, {CPU_THREADS} threads"
    print(f"device {device} ({machine}), "
          f"{str(dtype).removeprefix('torch.')}, SD 1.5-sized random models\n")
    memory = "peak allocated MB" if device.type == "cuda" else "memory growth MB"
    print(f"| what | render px | diffusion px | ms | vs guided prediction | {memory} |")
    print("|---|---:|---:|---:|---:|---:|")
    print(f"| guided noise prediction (ControlNet + UNet, batch 2) | | {resolution} | {1000 * base_s:.0f} | 1.00x | |")
    print(f"| SDS step (VAE encode + prediction + backward to the render) | {size} | {resolution} | "
          f"{1000 * step_s:.0f} | {step_s / base_s:.2f}x | {peak_mb(device) - (0 if device.type == 'cuda' else before):.0f} |")
    print_weights(models)
    return 0


if __name__ == "__main__":
    sys.exit(main())
