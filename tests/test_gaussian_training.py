"""Tests of the trainable Gaussians: the model, 3DGS's learning rates, adaptive density control
(clone, split, prune, opacity reset) with its optimiser bookkeeping, and checkpoints."""

from __future__ import annotations

import math

import pytest
import torch

from glimpse.gaussians.density import (
    SPLIT_COUNT,
    SPLIT_SCALE_DIVISOR,
    DensifyConfig,
    DensityStats,
    densify_and_prune,
    reset_opacity,
)
from glimpse.gaussians.model import GaussianModel, knn_scales
from glimpse.gaussians.optim import LearningRates, exponential_lr, make_optimizer, set_position_lr
from glimpse.gaussians.ply import read_gaussians_ply, write_gaussians_ply
from glimpse.gaussians.strategy import DefaultStrategy, HumanDensity, PeopleStrategy
from glimpse.io.checkpoint import fingerprint, load_checkpoint, save_checkpoint
from glimpse.render.projection import quat_to_rotation

RATES = LearningRates(1.6e-4, 1.6e-6, 100, 2.5e-3, 1.25e-4, 0.05, 5e-3, 1e-3)
DENSIFY = DensifyConfig(start=0, stop=100, every=1, grad_threshold=1e-3, reference_height_px=0.0, percent_dense=0.01,
                        min_opacity=0.005, max_screen_px=20.0, max_world_fraction=0.5, opacity_reset_every=50,
                        opacity_reset_value=0.01, max_gaussians=0)


def _model(n: int = 4, seed: int = 0) -> GaussianModel:
    g = torch.Generator().manual_seed(seed)
    model = GaussianModel.from_points(torch.randn(n, 3, generator=g), torch.rand(n, 3, generator=g),
                                      torch.full((n,), 0.005), opacity=0.5, sh_degree=2)
    with torch.no_grad():
        model.quats.copy_(torch.randn(n, 4, generator=g))
        model.sh_rest.normal_(generator=g)
    return model


def _stepped_optimizer(model: GaussianModel) -> torch.optim.Adam:
    """An Adam that has taken one step, so every parameter has moments to carry over."""
    optimizer = make_optimizer(model, RATES, extent=1.0)
    sum(p.square().sum() for p in model.parameters()).backward()
    optimizer.step()
    optimizer.zero_grad()
    return optimizer


def test_model_round_trips_through_the_standard_ply(tmp_path):
    model = _model(50)
    write_gaussians_ply(tmp_path / "g.ply", model.to_splats())
    again = GaussianModel.from_splats(read_gaussians_ply(tmp_path / "g.ply")[0])
    for (name, a), b in zip(model.parameter_dict().items(), again.parameter_dict().values()):
        assert torch.equal(a.detach(), b.detach()), name
    assert again.sh_degree == 2 and torch.allclose(again.opacities(), torch.full((50,), 0.5))


def test_from_points_gives_the_colour_back_at_degree_zero():
    rgb = torch.tensor([[0.1, 0.5, 0.9]])
    model = GaussianModel.from_points(torch.zeros(1, 3), rgb, torch.ones(1), 0.1, sh_degree=0)
    from glimpse.render.sh import sh_to_rgb

    assert torch.allclose(sh_to_rgb(0, model.sh().detach(), torch.tensor([[0.0, 0.0, 1.0]])), rgb, atol=1e-6)


def test_knn_scales_is_the_rms_distance_to_the_nearest_points():
    points = torch.tensor([[0.0, 0, 0], [1.0, 0, 0], [0, 2.0, 0], [10.0, 10, 10]]).numpy()
    scales = knn_scales(points, neighbours=2, floor=1e-3)
    assert scales[0] == pytest.approx(math.sqrt((1 + 4) / 2))
    assert knn_scales(points[:1], 3, floor=0.25).tolist() == [0.25]


def test_position_learning_rate_decays_log_linearly():
    assert exponential_lr(0, 1e-2, 1e-4, 100) == pytest.approx(1e-2)
    assert exponential_lr(50, 1e-2, 1e-4, 100) == pytest.approx(1e-3)
    assert exponential_lr(500, 1e-2, 1e-4, 100) == pytest.approx(1e-4)
    optimizer = make_optimizer(_model(), RATES, extent=30.0)
    assert set_position_lr(optimizer, RATES, 30.0, 100) == pytest.approx(1.6e-6 * 30)
    lrs = {g["name"]: g["lr"] for g in optimizer.param_groups}
    assert lrs == pytest.approx({"means": 1.6e-6 * 30, "sh_dc": 2.5e-3, "sh_rest": 1.25e-4, "opacity_logits": 0.05,
                                 "log_scales": 5e-3, "quats": 1e-3})


def test_densify_clones_small_splits_large_and_carries_adam_moments():
    model = _model(4)
    with torch.no_grad():
        model.log_scales[2:] = math.log(0.2)  # large: above percent_dense * extent = 0.01
    optimizer = _stepped_optimizer(model)
    before = {name: p.detach().clone() for name, p in model.parameter_dict().items()}
    moments = {g["name"]: optimizer.state[g["params"][0]]["exp_avg"].clone() for g in optimizer.param_groups}
    stats = DensityStats(4)
    stats.update(torch.tensor([[1.0, 0.0], [0.0, 0.0], [1.0, 0.0], [0.0, 0.0]]) * 1e-3, torch.tensor([3, 3, 3, 0]),
                 width=4, height=4)  # NDC gradient norms 2e-3 for Gaussians 0 and 2
    event = densify_and_prune(model, optimizer, stats, DENSIFY, extent=1.0, height=4, prune_large=False,
                              generator=torch.Generator().manual_seed(0))
    assert event == {"cloned": 1, "split": 1, "pruned": 0, "count": 4 - 1 + 1 + SPLIT_COUNT}
    # Rows: kept originals 0, 1, 3; the clone of 0; the children of 2.
    means = model.means.detach()
    assert torch.equal(means[:3], before["means"][[0, 1, 3]]) and torch.equal(means[3], before["means"][0])
    children = slice(4, 4 + SPLIT_COUNT)
    parent_scales = before["log_scales"][2].exp()
    assert torch.allclose(model.scales()[children], (parent_scales / SPLIT_SCALE_DIVISOR).expand(SPLIT_COUNT, 3))
    assert torch.equal(model.sh_rest.detach()[children], before["sh_rest"][[2, 2]])
    # Children lie within a few standard deviations of the parent, along its rotated axes.
    local = (means[children] - before["means"][2]) @ quat_to_rotation(before["quats"][2:3])[0]
    assert (local.abs() < 5 * parent_scales).all() and (local.abs() > 0).all()
    for group in optimizer.param_groups:
        param = group["params"][0]
        assert param is getattr(model, group["name"])
        state = optimizer.state[param]["exp_avg"]
        assert torch.equal(state[:3], moments[group["name"]][[0, 1, 3]])
        assert not state[3:].any()  # new Gaussians start with zero moments
    # The optimiser still steps the new parameters.
    sum(p.square().sum() for p in model.parameters()).backward()
    optimizer.step()


def test_threshold_follows_the_image_height():
    config = DensifyConfig(**{**vars(DENSIFY), "reference_height_px": 800.0})
    assert config.threshold_at(800) == pytest.approx(1e-3) and config.threshold_at(200) == pytest.approx(4e-3)
    assert DENSIFY.threshold_at(200) == pytest.approx(1e-3)


def test_prune_removes_transparent_and_after_reset_oversized_gaussians():
    model = _model(5)
    with torch.no_grad():
        model.opacity_logits[0] = -8.0  # opacity 3e-4 < min_opacity
        model.log_scales[1] = math.log(0.9)  # larger than 0.5 * extent
    optimizer = _stepped_optimizer(model)
    stats = DensityStats(5)
    stats.max_radii[2] = 30.0  # larger than max_screen_px on screen
    kept_means = model.means.detach()[[1, 2, 3, 4]].clone()
    event = densify_and_prune(model, optimizer, stats, DENSIFY, 1.0, 4, prune_large=False,
                              generator=torch.Generator())
    assert event["pruned"] == 1 and torch.equal(model.means.detach(), kept_means)
    stats = DensityStats(4)
    stats.max_radii[1] = 30.0
    event = densify_and_prune(model, optimizer, stats, DENSIFY, 1.0, 4, prune_large=True, generator=torch.Generator())
    assert event["pruned"] == 2 and torch.equal(model.means.detach(), kept_means[2:])
    assert all(optimizer.state[g["params"][0]]["exp_avg"].shape[0] == 2 for g in optimizer.param_groups)


def test_densification_respects_the_cap_keeping_the_largest_gradients():
    model = _model(6)
    optimizer = _stepped_optimizer(model)
    stats = DensityStats(6)
    stats.update(torch.tensor([[1.0, 0], [2, 0], [3, 0], [4, 0], [5, 0], [6, 0]]) * 1e-3, torch.ones(6), 2, 2)
    capped = DensifyConfig(**{**vars(DENSIFY), "max_gaussians": 8})
    before = model.means.detach().clone()
    event = densify_and_prune(model, optimizer, stats, capped, 1.0, 2, False, torch.Generator())
    assert event["cloned"] == 2 and len(model) == 8
    assert torch.equal(model.means.detach(), before[[0, 1, 2, 3, 4, 5, 4, 5]])


def test_opacity_reset_caps_opacities_and_restarts_their_moments():
    model = _model(3)
    with torch.no_grad():
        model.opacity_logits[0] = -6.0
    optimizer = _stepped_optimizer(model)
    reset_opacity(model, optimizer, 0.01)
    assert torch.allclose(model.opacities()[1:], torch.full((2,), 0.01))
    assert model.opacities()[0] < 0.01
    groups = {g["name"]: g["params"][0] for g in optimizer.param_groups}
    assert not optimizer.state[groups["opacity_logits"]]["exp_avg"].any()
    assert optimizer.state[groups["means"]]["exp_avg"].any()


def test_checkpoint_is_resumed_only_with_the_same_fingerprint(tmp_path, caplog):
    path = tmp_path / "work" / "checkpoint.pt"
    key = fingerprint({"a": 1}, ["manifest"])
    save_checkpoint(path, key, {"step": 7, "x": torch.arange(3)})
    state = load_checkpoint(path, key)
    assert state["step"] == 7 and torch.equal(state["x"], torch.arange(3))
    assert load_checkpoint(path, fingerprint({"a": 2}, ["manifest"])) is None
    path.write_bytes(b"truncated")
    assert load_checkpoint(path, key) is None and "unreadable" in caplog.text
    assert load_checkpoint(tmp_path / "absent.pt", key) is None


# --- the densification strategies ----------------------------------------------------------------------------

def test_the_default_strategy_follows_3dgs_schedule():
    schedule = DensifyConfig(**{**vars(DENSIFY), "start": 2, "stop": 9, "every": 3, "opacity_reset_every": 4})
    strategy = DefaultStrategy(schedule, extent=1.0)
    model = _model(4)
    optimizer = _stepped_optimizer(model)
    state = strategy.initialize_state(model)
    changed, reset = [], []
    for step in range(1, 13):
        gathered = state.views.clone()
        strategy.observe(state, torch.full((len(model), 2), 1.0), torch.ones(len(model)), 2, 2, step)
        assert torch.equal(state.views, gathered + 1) == (step < schedule.stop)  # nothing gathered from stop on
        with torch.no_grad():
            model.opacity_logits.fill_(2.0)  # opacity 0.88, far above the reset value
        if strategy.adapt(model, optimizer, state, step, 2, seed=step) is not None:
            changed.append(step)
            assert not state.views.any() and len(state.views) == len(model)  # gathering starts afresh
        if bool((model.opacities() <= schedule.opacity_reset_value + 1e-6).all()):
            reset.append(step)
    assert changed == [3, 6] and reset == [4, 8]


def test_the_people_strategy_densifies_at_its_steps_and_prunes_what_left_the_region():
    config = HumanDensity(densify_at=[20, 30], grad_threshold=1e-3, reference_height_px=0.0, split_scale_m=0.01,
                          max_gaussians=0, prune_every=10, prune_min_opacity=0.005, prune_max_scale_m=0.5)
    strategy = PeopleStrategy(config, lambda step: step // 10, free_after=1)  # a run at a tenth of the schedule
    assert strategy.densify_steps == {2, 3} and [s for s in range(1, 6) if strategy.prunes_at(s)] == [2, 3, 4, 5]
    model = _model(6)
    optimizer = _stepped_optimizer(model)
    state = strategy.initialize_state(model)
    assert strategy.adapt(model, optimizer, state, 1, 2, seed=0) is None
    inside = model.means.detach()[:, 0] > 0  # the region: x > 0
    kept = model.means.detach()[inside].clone()
    event = strategy.adapt(model, optimizer, state, 4, 2, seed=0, region=lambda means: means[:, 0] > 0)
    assert event == {"pruned_large_or_transparent": int((~inside).sum()), "count": int(inside.sum())}
    assert torch.equal(model.means.detach(), kept) and len(state.views) == len(model)
    state.update(torch.full((len(model), 2), 1.0), torch.ones(len(model)), 2, 2)  # every Gaussian over threshold
    event = strategy.adapt(model, optimizer, state, 3, 2, seed=0)
    assert event["cloned"] + event["split"] == len(kept) and event["count"] == 2 * len(kept)
