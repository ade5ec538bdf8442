"""The diffusion prior's parts, on tiny random diffusers models built here (no weights): the timestep
and reconstruction-weight schedules against the paper's numbers, the SDS camera sampler against its
stated distributions, the prompts, the skeleton condition against the projected keypoints, the SDS
gradient (w(t) (eps_hat - eps) in the latents, NaN-safe, reaching only the guided person), and loading
weights from local folders with the hub off."""

from __future__ import annotations

import math
import os
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from glimpse.body.config import BodyConfig, resolve_model_path
from glimpse.body.keypoints import keypoint_map
from glimpse.body.model import BodyModel
from glimpse.body.models import BodyModels
from glimpse.cameras.model import render_camera
from glimpse.cameras.orbit import orbit_camera
from glimpse.config import config_from_mapping, load_pipeline_yaml
from glimpse.errors import ConfigError, GlimpseError
from glimpse.gaussians.model import GaussianModel
from glimpse.metrics.losses import HARD_SURFACE_OFFSET
from glimpse.prior.sds.cameras import PART_JOINTS, SDSCameraConfig, fovy_deg, sample_view, view_kind, zoomed_camera
from glimpse.prior.sds.config import DiffusionConfig
from glimpse.prior.sds.control import skeleton_image
from glimpse.prior.sds.guidance import (
    DiffusionModels,
    SDSConfig,
    SDSText,
    add_noise,
    denoised_latents,
    encode_images,
    encode_text,
    sds_loss,
)
from glimpse.prior.sds.load import check_weight_paths, diffusion_device, load_diffusion
from glimpse.prior.sds.prompts import PromptConfig, view_prompts
from glimpse.prior.sds.schedule import TimestepConfig, recon_weight, sample_timestep, timestep_range
from glimpse.prior.skeleton import OPENPOSE18_COLOURS
from glimpse.render import RenderConfig, rasterize

diffusers = pytest.importorskip("diffusers")
from tests.tiny_diffusion import RENDER_PX, tiny_models, write_tiny_weights  # noqa: E402

PIPELINE = load_pipeline_yaml()
BODY = config_from_mapping(BodyConfig, PIPELINE["body"], "body")
TIMESTEPS = {name: TimestepConfig(name, 2000, 2000, [0.5, 0.98], [0.02, 0.3], [0.2, 0.98], 0.3, 0.3)
             for name in ("supplementary", "main_text", "official")}
CAMERAS = SDSCameraConfig(2.2, 49.1, [-54.0, 54.0], 2.86, {"head": 1.6, "upper": 1.4, "lower": 1.4}, 3000,
                          {"full": 0.5, "canonical": 0.5},
                          {"full": 0.2, "canonical": 0.2, "head": 0.2, "upper": 0.2, "lower": 0.2})


# --- schedules -----------------------------------------------------------------------------------------

@pytest.mark.parametrize(("name", "step", "expected"), [
    ("supplementary", 0, (0.5, 0.98)), ("supplementary", 1999, (0.5, 0.98)), ("supplementary", 3000, (0.26, 0.64)),
    ("supplementary", 4000, (0.02, 0.3)), ("supplementary", 9000, (0.02, 0.3)),
    ("main_text", 0, (0.2, 0.98)), ("main_text", 3000, (0.2, 0.64)), ("main_text", 5000, (0.2, 0.3)),
    ("official", 1999, (0.5, 0.98)), ("official", 2000, (0.3, 0.98)), ("official", 3000, (0.3, 0.64)),
    ("official", 4000, (0.02, 0.3)),
])
def test_timestep_ranges_follow_the_paper_and_the_official_code(name, step, expected):
    assert timestep_range(step, TIMESTEPS[name]) == pytest.approx(expected)


def test_sampled_timesteps_stay_in_range_and_the_reconstruction_weight_follows_the_maximum():
    generator = torch.Generator().manual_seed(0)
    samples = np.array([sample_timestep(3000, TIMESTEPS["supplementary"], 1000, generator) for _ in range(4000)])
    assert samples.min() >= 260 and samples.max() <= 640
    assert samples.min() < 265 and samples.max() > 635 and abs(samples.mean() - 450) < 6  # uniform over it
    assert recon_weight(-1, TIMESTEPS["supplementary"], 1e6) == 1.0
    assert recon_weight(0, TIMESTEPS["supplementary"], 1e6) == pytest.approx(1e6 * 0.98**2)  # 9.6e5
    assert recon_weight(5000, TIMESTEPS["supplementary"], 1e6) == pytest.approx(9e4)


# --- cameras --------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def body_model() -> BodyModel:
    return BodyModel.from_file(resolve_model_path(BODY), dtype=torch.float64)


def _posed(body_model: BodyModel):
    with torch.no_grad():
        out = body_model(torch.zeros(10), torch.zeros(1, 3), torch.zeros(1, 69), torch.zeros(1, 3))
    return out.vertices[0].numpy(), out.joints[0].numpy()


def test_view_kinds_follow_the_early_then_the_late_probabilities():
    rng = np.random.default_rng(0)
    early = [view_kind(100, CAMERAS, rng) for _ in range(3000)]
    late = [view_kind(3000, CAMERAS, rng) for _ in range(5000)]
    assert set(early) == {"full", "canonical"} and abs(early.count("full") / 3000 - 0.5) < 0.03
    for kind in ("full", "canonical", "head", "upper", "lower"):
        assert abs(late.count(kind) / 5000 - 0.2) < 0.02


def test_orbit_views_are_uniform_in_azimuth_and_elevation_at_the_stated_radius(body_model):
    vertices, joints = _posed(body_model)
    labels = body_model.weights.argmax(1).numpy()
    rng = np.random.default_rng(1)
    views = [sample_view("full", CAMERAS, vertices, labels, joints[0], 1.3, 128, rng) for _ in range(2000)]
    azimuths = np.array([v.azimuth_deg for v in views])
    elevations = np.array([v.elevation_deg for v in views])
    assert azimuths.min() >= -180 and azimuths.max() < 180 and abs(azimuths.std() - 360 / math.sqrt(12)) < 5
    assert elevations.min() >= -54 and elevations.max() <= 54 and abs(elevations.std() - 108 / math.sqrt(12)) < 2
    for view in views[:20]:
        assert np.linalg.norm(view.camera.centre - joints[0]) == pytest.approx(2.2 * 1.3)
        assert fovy_deg(view.camera) == pytest.approx(49.1)
        assert view.camera.project(joints[:1])[0][0] == pytest.approx([63.5, 63.5])  # looking at the pelvis


def test_a_zoomed_view_fits_its_part_to_the_crop(body_model):
    vertices, _ = _posed(body_model)
    labels = body_model.weights.argmax(1).numpy()
    for kind, scale in (("head", 1.6), ("lower", 1.4)):
        part = vertices[np.isin(labels, PART_JOINTS[kind])]
        camera = zoomed_camera(part, 30.0, 2.86, scale, 128)
        pixels, depth = camera.project(part)
        offset = np.abs(pixels - 63.5).max()
        assert (depth > 0).all() and offset == pytest.approx(64.0 / scale, rel=0.02)
        assert np.linalg.norm(camera.centre - 0.5 * (part.min(0) + part.max(0))) == pytest.approx(2.86)
    head = zoomed_camera(vertices[np.isin(labels, PART_JOINTS["head"])], 0.0, 2.86, 1.6, 128)
    assert fovy_deg(head) < 15.0  # a head fills the view: far narrower than the orbit's 49.1


# --- prompts and the skeleton ------------------------------------------------------------------------------

def test_prompts_carry_the_view_and_the_token_only_for_the_unet():
    config = PromptConfig("a photo of a {token} person, {view} view", 45.0, 135.0, "high quality", "two people",
                          {"head": "head"})
    prompts = view_prompts("p1", "back", "head", config)
    assert prompts.unet == "a photo of a <person-p1> person, back view, head, high quality"
    assert prompts.controlnet == "a photo of a person, back view, head, high quality"
    assert prompts.negative == "two people, front view"
    side = view_prompts("p1", "side", "full", config)
    assert side.negative == "two people" and "head" not in side.unet


def test_the_skeleton_is_drawn_at_the_projected_keypoints_and_hides_the_face_from_behind(body_model):
    vertices, joints = _posed(body_model)
    kmap = keypoint_map("openpose18", body_model.data)
    with torch.no_grad():
        keypoints = kmap(torch.as_tensor(joints[None]), torch.as_tensor(vertices[None]))[0].numpy()
    front = orbit_camera(joints[0], 0.0, 0.0, 2.2, 49.1, 128)
    image, pixels, shown = skeleton_image(keypoints, joints[15], front, 128, 2.0)
    assert shown.all()
    for k in range(18):
        u, v = np.rint(pixels[k]).astype(int)
        assert tuple(image[v, u]) == OPENPOSE18_COLOURS[k]  # the keypoint's own dot colour
    behind = orbit_camera(joints[0], 180.0, 0.0, 2.2, 49.1, 128)
    _, _, shown_behind = skeleton_image(keypoints, joints[15], behind, 128, 2.0)
    assert not shown_behind[[0, 14, 15]].any()  # nose and eyes turned away


# --- the SDS step -------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def models(tmp_path_factory) -> DiffusionModels:
    unet, controlnet, vae, text_encoder, tokenizer, scheduler = tiny_models(tmp_path_factory.mktemp("tiny"))
    return DiffusionModels(unet, controlnet, vae, text_encoder, tokenizer, scheduler, torch.device("cpu"))


@pytest.fixture(scope="module")
def text(models) -> SDSText:
    encoded = encode_text(models, ["a photo of a person", "a photo", "two people"])
    return SDSText(encoded[0:1], encoded[1:2], encoded[2:3])


SDS = SDSConfig(guidance_scale=50.0, controlnet_scale=0.7, resolution_px=RENDER_PX)


def test_the_gradient_in_the_latents_is_the_weighted_guided_noise_residual(models, text):
    rgb = torch.rand(2, 3, RENDER_PX, RENDER_PX, generator=torch.Generator().manual_seed(1))
    skeleton = torch.rand(2, 3, RENDER_PX, RENDER_PX, generator=torch.Generator().manual_seed(2))
    latents = encode_images(models, rgb).detach().requires_grad_(True)
    timestep = 600
    loss, _ = sds_loss(models, rgb, skeleton, text, timestep, torch.Generator().manual_seed(3), SDS)
    # the same step by hand, from the same noise
    from glimpse.prior.sds.guidance import predicted_noise
    noise = torch.randn(latents.shape, generator=torch.Generator().manual_seed(3))
    alpha_bar = models.alphas_cumprod[timestep]
    noisy = alpha_bar.sqrt() * latents.detach() + (1 - alpha_bar).sqrt() * noise
    expected = (1 - alpha_bar) * (predicted_noise(models, noisy, timestep, skeleton, text, SDS) - noise)
    assert loss.item() == pytest.approx(0.5 * expected.square().sum().item() / 2, rel=1e-5)
    # gradient in the latents: through the loss's own latents
    rgb_leaf = rgb.clone().requires_grad_(True)
    captured = {}
    original = models.vae.encode

    def spy(x):
        out = original(x)
        out.latent_dist.mean.retain_grad()
        captured["mean"] = out.latent_dist.mean
        return out

    models.vae.encode = spy
    try:
        loss, _ = sds_loss(models, rgb_leaf, skeleton, text, timestep, torch.Generator().manual_seed(3), SDS)
        loss.backward()
    finally:
        models.vae.encode = original
    scaling = models.vae.config.scaling_factor
    torch.testing.assert_close(captured["mean"].grad, expected * scaling / 2, rtol=1e-4, atol=1e-6)
    assert torch.isfinite(rgb_leaf.grad).all() and rgb_leaf.grad.abs().sum() > 0


def test_the_denoised_guess_inverts_the_forward_diffusion(models, text):
    latents = encode_images(models, torch.rand(1, 3, RENDER_PX, RENDER_PX, generator=torch.Generator().manual_seed(4)))
    noise = torch.randn(latents.shape, generator=torch.Generator().manual_seed(5))
    for timestep in (20, 500, 980):  # given the true noise, the guess is the clean latents
        noisy = add_noise(models, latents, noise, timestep)
        torch.testing.assert_close(denoised_latents(models, noisy, noise, timestep), latents, rtol=1e-4, atol=1e-4)
    _, info = sds_loss(models, torch.rand(1, 3, RENDER_PX, RENDER_PX), torch.zeros(1, 3, RENDER_PX, RENDER_PX), text,
                       500, torch.Generator().manual_seed(0), SDS, preview=True)
    assert info.preview.shape == (1, 3, RENDER_PX, RENDER_PX) and 0 <= info.preview.min() <= info.preview.max() <= 1
    assert sds_loss(models, torch.rand(1, 3, RENDER_PX, RENDER_PX), torch.zeros(1, 3, RENDER_PX, RENDER_PX), text,
                    500, torch.Generator().manual_seed(0), SDS)[1].preview is None  # no decoding unless asked


def test_a_nan_prediction_gives_a_zero_gradient_and_is_counted(models, text, monkeypatch):
    import glimpse.prior.sds.guidance as guidance

    monkeypatch.setattr(guidance, "predicted_noise", lambda *args: torch.full((1, 4, 8, 8), float("nan")))
    rgb = torch.rand(1, 3, RENDER_PX, RENDER_PX, requires_grad=True)
    loss, info = sds_loss(models, rgb, torch.zeros(1, 3, RENDER_PX, RENDER_PX), text, 500,
                          torch.Generator().manual_seed(0), SDS)
    loss.backward()
    assert loss.item() == 0.0 and info.grad_norm == 0.0 and (rgb.grad == 0).all()
    assert info.nonfinite == 4 * 8 * 8  # zeroed, and counted: the prior reports it


def _gaussians(seed: int, offset: float) -> GaussianModel:
    generator = torch.Generator().manual_seed(seed)
    count = 300
    means = torch.randn(count, 3, generator=generator) * 0.25 + torch.tensor([offset, 0.0, 0.0])
    return GaussianModel.from_points(means, torch.rand(count, 3, generator=generator), torch.full((count,), 0.03), 0.9, 0)


def test_sds_gradients_reach_the_guided_persons_colours_and_positions_only(models, text):
    guided, other = _gaussians(0, 0.0), _gaussians(1, 3.0)
    camera = render_camera(orbit_camera(np.zeros(3), 0.0, 0.0, 2.2, 49.1, 48), torch.device("cpu"))
    rgb = rasterize(camera, **guided.render_inputs(0), background=torch.ones(3),
                    settings=RenderConfig("auto", 0, antialiased=False)).rgb  # the guided person alone
    loss, _ = sds_loss(models, rgb.permute(2, 0, 1)[None], torch.zeros(1, 3, RENDER_PX, RENDER_PX), text, 700,
                       torch.Generator().manual_seed(0), SDS)
    loss.backward()
    assert guided.sh_dc.grad.abs().sum() > 0 and guided.means.grad.abs().sum() > 0
    assert other.sh_dc.grad is None and other.means.grad is None


# --- loading the weights --------------------------------------------------------------------------------------

DIFFUSION = config_from_mapping(DiffusionConfig, PIPELINE["diffusion"], "diffusion")


def test_weights_load_from_local_folders_with_the_hub_off(tmp_path):
    sd, controlnet = write_tiny_weights(tmp_path)
    config = replace(DIFFUSION, sd_path=str(sd), controlnet_path=str(controlnet), allow_cpu=True)
    os.environ.pop("HF_HUB_OFFLINE", None)
    loaded = load_diffusion(config, torch.device("cpu"))
    assert "HF_HUB_OFFLINE" not in os.environ  # switched off only while loading
    unet, *_ = tiny_models(tmp_path / "again")  # the same seed: the same weights
    for name, value in unet.state_dict().items():
        torch.testing.assert_close(loaded.unet.state_dict()[name], value)
    assert loaded.train_timesteps == 1000 and not any(p.requires_grad for p in loaded.unet.parameters())
    encoded = encode_text(loaded, ["a photo", "a", "b"])
    loss, _ = sds_loss(loaded, torch.rand(1, 3, 32, 32), torch.zeros(1, 3, RENDER_PX, RENDER_PX),
                       SDSText(encoded[0:1], encoded[1:2], encoded[2:3]), 400, torch.Generator().manual_seed(0), SDS)
    assert torch.isfinite(loss)


def test_missing_or_wrong_weights_are_refused_with_the_parameter_to_set(tmp_path):
    with pytest.raises(ConfigError, match=r"diffusion\.sd_path and diffusion\.controlnet_path"):
        check_weight_paths(DIFFUSION)
    (tmp_path / "sd" / "unet").mkdir(parents=True)
    (tmp_path / "cn").mkdir()
    with pytest.raises(ConfigError, match=r"lacks vae/, text_encoder/, tokenizer/, scheduler/"):
        check_weight_paths(replace(DIFFUSION, sd_path=str(tmp_path / "sd"), controlnet_path=str(tmp_path / "cn")))
    checkpoint = tmp_path / "v1-5-pruned.safetensors"
    checkpoint.write_bytes(b"0")
    with pytest.raises(ConfigError, match=r"single-file checkpoint.*set diffusion\.sd_config_path"):
        check_weight_paths(replace(DIFFUSION, sd_path=str(checkpoint), controlnet_path=str(tmp_path / "cn")))
    with pytest.raises(ConfigError, match=r"diffusion\.sd_config_path: .* lacks unet/, vae/"):
        check_weight_paths(replace(DIFFUSION, sd_path=str(checkpoint), sd_config_path=str(tmp_path / "cn"),
                                   controlnet_path=str(tmp_path / "cn")))


def test_the_test_checkpoints_are_in_the_original_layouts_diffusers_converts():
    from diffusers.loaders.single_file_utils import (
        convert_controlnet_checkpoint,
        convert_ldm_unet_checkpoint,
        convert_ldm_vae_checkpoint,
    )

    from tests.original_checkpoints import original_controlnet_state, original_state

    unet, controlnet, vae, text_encoder, _, _ = tiny_models(Path(tempfile.mkdtemp()))
    state = original_state(unet, vae, text_encoder)
    for model, converted in ((unet, convert_ldm_unet_checkpoint(state, unet.config)),
                             (vae, convert_ldm_vae_checkpoint(state, vae.config)),
                             (controlnet, convert_controlnet_checkpoint(original_controlnet_state(controlnet),
                                                                        controlnet.config))):
        expected = model.state_dict()
        assert set(converted) == set(expected)
        assert all(torch.equal(converted[name], value) for name, value in expected.items())


def test_single_file_checkpoints_load_with_local_configs(tmp_path):
    from tests.original_checkpoints import write_original_checkpoints

    files = write_original_checkpoints(tmp_path)
    config = replace(DIFFUSION, sd_path=str(files["sd"]), sd_config_path=str(files["sd_configs"]),
                     controlnet_path=str(files["controlnet"]),
                     controlnet_config_path=str(files["controlnet_configs"]), allow_cpu=True)
    loaded = load_diffusion(config, torch.device("cpu"))
    unet, controlnet, vae, text_encoder, tokenizer, _ = tiny_models(tmp_path / "again")  # the same weights
    for name, model in (("unet", unet), ("controlnet", controlnet), ("vae", vae), ("text_encoder", text_encoder)):
        for key, value in model.state_dict().items():
            assert torch.equal(getattr(loaded, name).state_dict()[key], value), (name, key)
    assert loaded.tokenizer("a person").input_ids == tokenizer("a person").input_ids
    assert loaded.train_timesteps == 1000


def test_a_single_file_that_does_not_fit_its_configs_is_refused_naming_both(tmp_path):
    from safetensors.torch import load_file, save_file

    from tests.original_checkpoints import write_original_checkpoints

    files = write_original_checkpoints(tmp_path)
    state = load_file(str(files["sd"]))
    dropped = next(name for name in state if name.startswith("model.diffusion_model.output_blocks"))
    del state[dropped]
    save_file(state, str(files["sd"]))
    config = replace(DIFFUSION, sd_path=str(files["sd"]), sd_config_path=str(files["sd_configs"]),
                     controlnet_path=str(files["controlnet"]),
                     controlnet_config_path=str(files["controlnet_configs"]), allow_cpu=True)
    with pytest.raises(GlimpseError, match=r"tiny-sd15\.safetensors: its UNet does not fit the configs in "
                                           r".*sd_configs: weights 1 missing \(e\.g\. up_blocks"):
        load_diffusion(config, torch.device("cpu"))


def test_without_cuda_sds_stops_unless_the_cpu_is_allowed():
    with pytest.raises(GlimpseError, match="needs a CUDA GPU.*diffusion.allow_cpu"):
        diffusion_device(DIFFUSION, torch.device("cpu"))
    assert diffusion_device(replace(DIFFUSION, allow_cpu=True), torch.device("cpu")) == (torch.device("cpu"),
                                                                                        torch.float32)
    assert diffusion_device(DIFFUSION, torch.device("cuda"))[1] == torch.float16


# --- the prior in stage 06 ----------------------------------------------------------------------------------

def _sds_prior(tmp_path, body_model, combine: str = "separate_steps", preview_dir=None, **changes):
    from glimpse.body.params import BodyParams
    from glimpse.humans.person import initial_person
    from glimpse.humans.visibility import BodyVisibility
    from glimpse.prior import PriorContext, make_prior
    from glimpse.prior.sds.identity import new_identity, save_identity

    sd, controlnet = write_tiny_weights(tmp_path / "weights")
    config = replace(DIFFUSION, sd_path=str(sd), controlnet_path=str(controlnet), allow_cpu=True, start_at=10,
                     resolution_px=RENDER_PX, early_resolution_px=RENDER_PX, combine=combine, **changes)
    loaded = load_diffusion(config, torch.device("cpu"))
    people = []
    for k, pid in enumerate(("p0", "p1")):
        frames = 3
        pose = np.zeros((frames, 69))
        pose[:, 47] = np.linspace(-0.5, 0.5, frames)  # a bent elbow that changes
        body = BodyParams(np.arange(frames), np.zeros(10), np.zeros((frames, 3)), pose,
                          np.tile([2.0 * k, 0.0, 0.0], (frames, 1)), 1.0, "free", np.zeros(frames, bool))
        people.append(initial_person(pid, body_model.to(torch.float32), body, 30.0, BODY.skinning, 0.5, 0.9, 3, 1))
        save_identity(new_identity(loaded, f"<person-{pid}>"), loaded,
                      tmp_path / "05" / pid / "identity" / "identity.safetensors")
    visibility = {p.pid: BodyVisibility.empty(body_model.num_vertices) for p in people}
    context = PriorContext(people, visibility, BodyModels(body_model), RenderConfig("auto", 1, False), 0, lambda i: i,
                           tmp_path / "05", preview_dir)
    return make_prior("sds", context, config), people


def test_an_sds_step_reaches_only_the_guided_persons_gaussians(tmp_path):
    body_model = BodyModel.from_file(resolve_model_path(BODY))
    prior, people = _sds_prior(tmp_path, body_model)
    assert prior.losses(0, people) == {} and list(prior.separate_losses(0)) == []  # before start_at
    assert prior.recon_weight(0) == 1.0
    assert prior.recon_weight(prior.start) == pytest.approx(1e6 * 0.98**2)
    steps = list(prior.separate_losses(prior.start))
    assert [index for index, _ in steps] == [0, 1]  # every person, in turn
    index, loss = steps[0]
    loss.backward()
    guided, other = people[0].model, people[1].model
    assert guided.sh_dc.grad.abs().sum() > 0 and guided.means.grad.abs().sum() > 0
    assert other.sh_dc.grad is None and other.means.grad is None
    again = prior.person_loss(prior.start, 0)
    assert again.item() == pytest.approx(loss.item(), rel=1e-5)  # (seed, iteration, person) fix every draw


def test_the_hard_surface_term_of_an_sds_render_is_weighted_by_lambda_recon(tmp_path):
    body_model = BodyModel.from_file(resolve_model_path(BODY))
    prior, people = _sds_prior(tmp_path, body_model)
    step = prior.start + 5
    sds, surface = prior.person_terms(step, 1)
    weight = DIFFUSION.hard_surface * recon_weight(5, prior.timesteps, DIFFUSION.recon_scale)
    assert DIFFUSION.hard_surface > 0 and weight > 1e4  # the official code's 0.1 x lambda_rgb
    assert prior.person_loss(step, 1).item() == pytest.approx(sds.item() + weight * surface.item(), rel=1e-5)
    assert 0.0 < surface.item() <= HARD_SURFACE_OFFSET  # alphas between 0 and 1, not all of them 0 or 1
    surface.backward()
    guided, other = people[1].model, people[0].model
    assert guided.opacity_logits.grad.abs().sum() > 0 and other.opacity_logits.grad is None


def test_previews_are_written_only_when_asked_and_on_their_steps(tmp_path):
    from glimpse.io.images import read_rgb

    body_model = BodyModel.from_file(resolve_model_path(BODY))
    previews = tmp_path / "previews"
    prior, _ = _sds_prior(tmp_path, body_model, preview_dir=previews, preview_every=2)
    for step in range(prior.start, prior.start + 3):
        prior.person_terms(step, 0)
    written = sorted(path.relative_to(previews).as_posix() for path in previews.rglob("*.png"))
    assert written == [f"p0/{prior.start:06d}.png", f"p0/{prior.start + 2:06d}.png"]
    assert read_rgb(previews / written[0]).shape == (RENDER_PX, 3 * RENDER_PX, 3)  # render | skeleton | guess
    quiet, _ = _sds_prior(tmp_path / "quiet", body_model, preview_dir=tmp_path / "none")  # preview_every 0
    quiet.person_terms(quiet.start, 0)
    assert not (tmp_path / "none").exists()


def test_summed_sds_is_one_term_of_the_iterations_loss(tmp_path):
    body_model = BodyModel.from_file(resolve_model_path(BODY))
    prior, people = _sds_prior(tmp_path, body_model, combine="summed")
    terms = prior.losses(prior.start, people[:1])  # every person is guided, not only the view's
    assert set(terms) == {"loss_sds"} and list(prior.separate_losses(prior.start)) == []
    terms["loss_sds"].backward()
    assert all(p.model.sh_dc.grad.abs().sum() > 0 for p in people)
