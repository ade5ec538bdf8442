"""CustomDiffusion identities on tiny random models: a training step lowers the loss and changes only
the person's token row and K/V projections; identities save and load exactly; swapping people's
processors in and out of the shared UNet."""

from __future__ import annotations

import pytest
import torch

from glimpse.prior.sds.guidance import DiffusionModels
from glimpse.prior.sds.identity import IdentitySwitch, load_identity, new_identity, save_identity
from glimpse.prior.sds.train_identity import (
    IdentityConfig, IdentityExample, SampleConfig, identity_loss, train_identity,
)

pytest.importorskip("diffusers")
from tests.tiny_diffusion import RENDER_PX, tiny_models  # noqa: E402

TOKEN = "<person-p0>"


def _models(folder, seed: int = 0) -> DiffusionModels:
    unet, controlnet, vae, text_encoder, tokenizer, scheduler = tiny_models(folder, seed)
    return DiffusionModels(unet, controlnet, vae, text_encoder, tokenizer, scheduler, torch.device("cpu"))


def _config(**values) -> IdentityConfig:
    return IdentityConfig(**values, controlnet_scale=1.0, reference_prompt="a photo of a {token} person",
                          samples=SampleConfig(0, 1, 7.5))


def _examples(count: int = 4) -> list[IdentityExample]:
    generator = torch.Generator().manual_seed(5)
    examples = []
    for k in range(count):
        image = torch.rand(3, RENDER_PX, RENDER_PX, generator=generator)
        mask = torch.zeros(RENDER_PX, RENDER_PX)
        mask[8:56, 20:44] = 1.0
        view = ("front", "back", "side", "front")[k % 4]
        examples.append(IdentityExample(image, mask, torch.rand(3, RENDER_PX, RENDER_PX, generator=generator),
                                        f"a photo of a {TOKEN} person, {view} view", f"a photo of a person, {view} view"))
    return examples


def _snapshot(module: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in module.state_dict().items() if "processor" not in k}


def test_one_step_lowers_the_loss_and_trains_only_the_token_and_the_kv_projections(tmp_path):
    models = _models(tmp_path)
    identity = new_identity(models, TOKEN)
    examples = _examples()
    config = _config(steps=1, learning_rate=1e-3, batch_size=4, background_weight=0.5)
    before = {name: _snapshot(getattr(models, name)) for name in ("unet", "controlnet", "vae", "text_encoder")}
    kv_before = [p.detach().clone() for p in identity.kv_parameters()]
    timesteps, noise = torch.tensor([100, 300, 500, 900]), torch.randn(4, 4, 8, 8, generator=torch.Generator().manual_seed(1))
    switch = IdentitySwitch(models.unet)
    switch.use(identity)
    with torch.no_grad():
        loss_before = float(identity_loss(models, examples, timesteps, noise, config))
    # the step draws its own crops, timesteps and noise; the loss is compared on a fixed batch
    train_identity(models, identity, examples, config, torch.Generator().manual_seed(0))
    switch.use(identity)
    with torch.no_grad():
        loss_after = float(identity_loss(models, examples, timesteps, noise, config))
    assert loss_after < loss_before
    for name, saved in before.items():
        now = _snapshot(getattr(models, name))
        for key, value in saved.items():
            if name == "text_encoder" and key.endswith("token_embedding.weight"):
                changed = (now[key] != value).any(dim=1)
                assert changed.nonzero().flatten().tolist() == [identity.token_id]
            else:
                assert torch.equal(now[key], value), f"{name}.{key} changed"
    assert all(not torch.equal(a, b) for a, b in zip(kv_before, identity.kv_parameters()))


def test_a_saved_identity_loads_into_fresh_models_and_predicts_the_same(tmp_path):
    models = _models(tmp_path / "a")
    identity = new_identity(models, TOKEN)
    config = _config(steps=2, learning_rate=1e-3, batch_size=2, background_weight=1.0)
    train_identity(models, identity, _examples(), config, torch.Generator().manual_seed(0))
    path = tmp_path / "identity" / "identity.safetensors"
    save_identity(identity, models, path)
    fresh = _models(tmp_path / "b")
    loaded = load_identity(fresh, path)
    assert loaded.token == TOKEN
    table, fresh_table = (m.text_encoder.get_input_embeddings().weight for m in (models, fresh))
    torch.testing.assert_close(fresh_table[loaded.token_id], table[identity.token_id])
    examples, timesteps = _examples(2), torch.tensor([200, 700])
    noise = torch.randn(2, 4, 8, 8, generator=torch.Generator().manual_seed(2))
    losses = []
    for m, person in ((models, identity), (fresh, loaded)):
        IdentitySwitch(m.unet).use(person)
        with torch.no_grad():
            losses.append(float(identity_loss(m, examples, timesteps, noise, config)))
    assert losses[0] == pytest.approx(losses[1], rel=1e-6)


def test_swapping_a_person_out_restores_the_plain_unet(tmp_path):
    models = _models(tmp_path)
    switch = IdentitySwitch(models.unet)
    identity = new_identity(models, TOKEN)
    with torch.no_grad():
        for processor in identity.processors.values():
            processor.to_k_custom_diffusion.weight.mul_(1.5)  # a person whose K differs from the plain UNet's
    examples, timesteps = _examples(1), torch.tensor([400])
    noise = torch.randn(1, 4, 8, 8, generator=torch.Generator().manual_seed(3))
    config = _config(steps=1, learning_rate=1e-3, batch_size=1, background_weight=1.0)
    with torch.no_grad():
        plain = float(identity_loss(models, examples, timesteps, noise, config))
        switch.use(identity)
        personal = float(identity_loss(models, examples, timesteps, noise, config))
        switch.use(None)
        again = float(identity_loss(models, examples, timesteps, noise, config))
    assert personal != plain and again == plain


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
def test_training_in_half_precision_steps_float32_weights_and_stays_finite(tmp_path, dtype):
    """The GPU runs the models in float16 (diffusion.half_precision): the trained token row and K/V weights
    stay float32, so Adam's small steps land and nothing turns to NaN; the frozen parts keep their dtype."""
    models = _models(tmp_path)
    for part in (models.unet, models.controlnet, models.vae, models.text_encoder):
        part.to(dtype)
    identity = new_identity(models, TOKEN)
    table = models.text_encoder.get_input_embeddings().weight
    row_before = table[identity.token_id].detach().clone()
    kv_before = [p.detach().clone() for p in identity.kv_parameters()]
    assert all(p.dtype == torch.float32 for p in identity.kv_parameters())
    config = _config(steps=2, learning_rate=1e-4, batch_size=2, background_weight=0.5)
    losses = train_identity(models, identity, _examples(), config, torch.Generator().manual_seed(0))
    assert all(torch.isfinite(torch.tensor(losses)))
    assert table.dtype == dtype and models.unet.dtype == dtype
    assert torch.isfinite(table).all() and not torch.equal(table[identity.token_id], row_before)
    for before, after in zip(kv_before, identity.kv_parameters()):
        assert after.dtype == torch.float32 and torch.isfinite(after).all() and not torch.equal(before, after)
