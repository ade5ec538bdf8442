"""Stages 05 and 06 with the diffusion prior (prior.kind sds) on the tiny `sparse` fixture, with tiny random
diffusion models built here: identities trained, SDS steps taken on every person from start_at (each on
its own optimiser step), the reconstruction loss weighted by lambda_recon, and the stage's outputs written.
It proves the plumbing; with random weights the people do not look better."""

from __future__ import annotations

import pytest

from glimpse.fixtures.scenes import make_scene
from tests.stage_helpers import read_json, run

pytest.importorskip("diffusers")
from tests.tiny_diffusion import RENDER_PX, write_tiny_weights  # noqa: E402

ITERATIONS = 24  # 06_joint_opt.schedule_scale 0.002 of 12000
SCALE = 0.002


def test_stages_05_and_06_run_with_the_sds_prior(tmp_path):
    scene = make_scene("sparse", tmp_path / "scene", "tiny", seed=0)
    sd, controlnet = write_tiny_weights(tmp_path / "weights")
    params = (f"prior.kind=sds diffusion.sd_path={sd} diffusion.controlnet_path={controlnet} diffusion.allow_cpu=true "
              f"diffusion.resolution_px={RENDER_PX} diffusion.early_resolution_px={RENDER_PX} diffusion.start_at=10000 "
              "04_bg_pretrain.schedule_scale=0.005 "
              f"05_textual_inversion.crop_size_px={RENDER_PX} 05_textual_inversion.min_mask_px=20 "
              "05_textual_inversion.identity.steps=2 05_textual_inversion.identity.batch_size=2 "
              "05_textual_inversion.identity.samples.count=1 05_textual_inversion.identity.samples.steps=2 "
              f"06_joint_opt.schedule_scale={SCALE} 06_joint_opt.render_video=false")
    for stage in ("01_sfm", "02_smpl_fit", "03_masks", "04_bg_pretrain", "05_textual_inversion", "06_joint_opt"):
        out = run(stage, scene, tmp_path / "out", params)
    report = read_json(out / "report.json")
    assert report["prior"] == "sds" and report["iterations"] == ITERATIONS
    start = int(10000 * SCALE)  # diffusion.start_at under the schedule: iteration 20
    history = {entry["iteration"]: entry for entry in report["loss_history"]}
    people = sorted(report["people"])
    assert len(people) >= 1
    assert report["prior_guidance_nonfinite_steps"] == {pid: 0 for pid in people}  # tiny fp32 models: finite
    for iteration, entry in history.items():
        assert ("loss_sds_separate" in entry) == (iteration >= start), iteration
        if iteration >= start:  # lambda_recon = 1e6 tau_max^2 weighs the reconstruction from start_at
            assert entry["loss_sds_separate"] > 0 and entry["total"] > 1e3 * entry["mse"]
        else:
            assert entry["total"] < 10 * (entry["mse"] + entry["dssim"] + entry["lpips"] + 1)
    for pid in people:
        assert (out / "humans" / pid / "canonical.ply").is_file()
    identity = read_json(tmp_path / "out" / "sparse_tiny" / "05_textual_inversion" / "manifest.json")["summary"]
    assert identity["identity"] == "trained"
