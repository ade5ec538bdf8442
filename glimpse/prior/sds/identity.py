"""Each person's identity in the diffusion model: CustomDiffusion (paper Sec. 4.4, supplementary).

A person j gets a new token ``<person-pj>`` in the shared tokenizer, its own row in the text
encoder's embedding table (started from the word "person"), and their own key/value projections in
every cross-attention layer of the UNet (CustomDiffusion's attention processors, started from the
UNet's). Training (stage 05) changes only those: the noise-prediction MSE on the person's crops,
the UNet reading the crop's view prompt with the token, the ControlNet (frozen) reading the
skeleton image and the prompt without the token. Every person's token stays in the shared
tokenizer; their attention processors are swapped into the one UNet when they are guided
(:meth:`IdentitySwitch.use`), never one pipeline per person.

Saved per person as safetensors (``identity/identity.safetensors``): the token's embedding and the
K/V weights, the token in the metadata.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor, nn

from glimpse.errors import GlimpseError
from glimpse.prior.sds.guidance import DiffusionModels

IDENTITY_FORMAT = "glimpse-identity/1"
INIT_WORD = "person"  # the token's embedding starts as this word's
EMBEDDING_KEY = "token_embedding"
TRAINABLE_DTYPE = torch.float32  # what identity training steps, whatever precision the models run in
CROSS_ATTENTION_SUFFIX = "attn2.processor"  # diffusers' name of a transformer block's cross-attention


def add_token(models: DiffusionModels, token: str) -> int:
    """Add ``token`` to the tokenizer (once) with an embedding row copied from INIT_WORD's; its id."""
    tokenizer, encoder = models.tokenizer, models.text_encoder
    if token not in tokenizer.get_vocab():
        tokenizer.add_tokens([token])
        init_ids = tokenizer(INIT_WORD, add_special_tokens=False).input_ids
        encoder.resize_token_embeddings(len(tokenizer), mean_resizing=False)
        table = encoder.get_input_embeddings().weight
        with torch.no_grad():
            table[-1] = table[init_ids].mean(0)
    return int(tokenizer.convert_tokens_to_ids(token))


def custom_processors(unet: nn.Module, device: torch.device) -> dict[str, nn.Module]:
    """Fresh CustomDiffusion processors for every cross-attention layer of ``unet``, their K/V projections
    copied from the layer's (so the model starts unchanged), keyed by processor name. They are float32 even
    when the UNet runs in float16: Adam's steps on them would vanish below float16's spacing (and its epsilon
    is 0 there); the processors cast the text states in and their keys and values back out (diffusers)."""
    from diffusers.models.attention_processor import CustomDiffusionAttnProcessor2_0

    processors = {}
    for name in unet.attn_processors:
        if not name.endswith(CROSS_ATTENTION_SUFFIX):
            continue
        layer = unet.get_submodule(name.removesuffix(".processor"))
        processor = CustomDiffusionAttnProcessor2_0(train_kv=True, train_q_out=False,
                                                    hidden_size=layer.to_k.out_features,
                                                    cross_attention_dim=layer.to_k.in_features)
        processor.to_k_custom_diffusion.weight.data.copy_(layer.to_k.weight.data)
        processor.to_v_custom_diffusion.weight.data.copy_(layer.to_v.weight.data)
        processors[name] = processor.to(device=device, dtype=TRAINABLE_DTYPE)
    return processors


@dataclass
class PersonIdentity:
    """One person's token, its id, and their cross-attention processors (name -> module)."""

    token: str
    token_id: int
    processors: dict[str, nn.Module]

    def kv_parameters(self) -> list[Tensor]:
        return [p for processor in self.processors.values() for p in processor.parameters()]


class IdentitySwitch:
    """Swaps people's attention processors into the shared UNet (and back to the plain UNet's)."""

    def __init__(self, unet: nn.Module):
        self.unet = unet
        self.plain = dict(unet.attn_processors)

    def use(self, identity: PersonIdentity | None) -> None:
        processors = dict(self.plain)
        if identity is not None:
            processors.update(identity.processors)
        self.unet.set_attn_processor(processors)


def new_identity(models: DiffusionModels, token: str) -> PersonIdentity:
    return PersonIdentity(token, add_token(models, token), custom_processors(models.unet, models.device))


def save_identity(identity: PersonIdentity, models: DiffusionModels, path: Path) -> None:
    """Write the token's embedding and the K/V weights as safetensors at ``path``."""
    from safetensors.torch import save_file

    tensors = {EMBEDDING_KEY: models.text_encoder.get_input_embeddings().weight[identity.token_id].detach()}
    for name, processor in identity.processors.items():
        for key, value in processor.state_dict().items():
            tensors[f"{name}.{key}"] = value.detach()
    path.parent.mkdir(parents=True, exist_ok=True)
    save_file({k: v.contiguous().cpu() for k, v in tensors.items()}, str(path),
              metadata={"format": IDENTITY_FORMAT, "token": identity.token})


def load_identity(models: DiffusionModels, path: Path) -> PersonIdentity:
    """A person's identity from ``path`` (save_identity's file), its token added to the shared tokenizer."""
    from safetensors import safe_open

    with safe_open(str(path), framework="pt") as handle:
        metadata = handle.metadata() or {}
        if metadata.get("format") != IDENTITY_FORMAT:
            raise GlimpseError(f"{path}: not a {IDENTITY_FORMAT} file; rerun stage 05 with prior.kind sds")
        tensors = {key: handle.get_tensor(key) for key in handle.keys()}
    identity = new_identity(models, metadata["token"])
    table = models.text_encoder.get_input_embeddings().weight
    with torch.no_grad():
        table[identity.token_id] = tensors.pop(EMBEDDING_KEY).to(table)
    for name, processor in identity.processors.items():
        state = {key.removeprefix(f"{name}."): value for key, value in tensors.items() if key.startswith(f"{name}.")}
        if not state:
            raise GlimpseError(f"{path}: no weights for {name}; it was trained for another UNet")
        processor.load_state_dict(state)  # copied into the processor's own device and dtype
    return identity
