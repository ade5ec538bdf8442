"""Body shapes the user knows (02_smpl_fit.person_shapes): read with clear errors, held fixed in the fit, and
the person placed metrically on the common floor."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from glimpse.body.model import BodyModel
from glimpse.body.models import BodyModels
from glimpse.body.params import BodyParams, read_body_shape, write_body_params
from glimpse.config import REPO_ROOT, config_from_mapping, load_pipeline_yaml
from glimpse.errors import ConfigError, GlimpseError
from glimpse.fit.config import FitConfig, stated_person_shapes
from glimpse.fit.evaluate import body_joints
from glimpse.fit.stage import Fitter
from glimpse.fixtures.scenes import FREE_BODY, keep_only_2d_keypoints, make_scene
from glimpse.io.cameras_json import read_cameras_json
from glimpse.scene import load_scene


@pytest.fixture(scope="module")
def model():
    return BodyModel.from_file(FREE_BODY, dtype=torch.float64)


def _config(**overrides) -> FitConfig:
    raw = load_pipeline_yaml()["02_smpl_fit"]
    return config_from_mapping(FitConfig, {**raw, "overlay": False, **overrides}, "x")


def test_shape_entries_and_files_are_checked_with_one_clear_error(model, tmp_path):
    # relative to the repository, as every path parameter
    assert stated_person_shapes(_config(person_shapes=[" p0 = a.npz", f"p1={tmp_path / 'c.npz'}"])) == {
        "p0": REPO_ROOT / "a.npz", "p1": tmp_path / "c.npz"}
    for entries, message in ((["p0"], "not PID=PATH"), (["p0="], "not PID=PATH"), (["=a.npz"], "not PID=PATH"),
                             (["p0=a.npz", "p0=b.npz"], "given twice")):
        with pytest.raises(ConfigError, match=message):
            stated_person_shapes(_config(person_shapes=entries))
    betas = np.linspace(-1.0, 1.0, model.num_betas)
    run_output = tmp_path / "body.npz"  # an earlier run's body.npz is a shape file
    write_body_params(run_output, BodyParams(np.arange(2), betas, np.zeros((2, 3)), np.zeros((2, 69)),
                                             np.zeros((2, 3)), 1.0, "free", np.zeros(2, bool)))
    assert np.array_equal(read_body_shape(run_output, model.num_betas, "free"), betas)
    np.savez(tmp_path / "plain.npz", betas=betas)
    assert np.array_equal(read_body_shape(tmp_path / "plain.npz", model.num_betas, "smpl"), betas)
    np.savez(tmp_path / "none.npz", shape=betas)
    np.savez(tmp_path / "short.npz", betas=betas[:4])
    np.savez(tmp_path / "nan.npz", betas=np.full(model.num_betas, np.nan))
    (tmp_path / "text.npz").write_text("not an archive")
    for name, body_model, message in (("none.npz", "free", "no `betas` array"),
                                      ("short.npz", "free", "must be 10 finite numbers"),
                                      ("nan.npz", "free", "must be 10 finite numbers"),
                                      ("body.npz", "smpl", "for the 'free' body model; this scene uses 'smpl'"),
                                      ("text.npz", "free", "cannot read a body shape"),
                                      ("missing.npz", "free", "cannot read a body shape")):
        with pytest.raises(GlimpseError, match=f"{name}: .*{message}"):
            read_body_shape(tmp_path / name, model.num_betas, body_model)


def _distance_ratio(model, params, true: dict, centre: np.ndarray) -> float:
    """Median over the fitted frames of the fitted pelvis's distance from ``centre`` over the true one's."""
    rows = np.searchsorted(true["frame_ids"], params.frame_ids)
    fitted = body_joints(model, params.betas, params.global_orient, params.body_pose, params.transl)[:, 0]
    real = body_joints(model, true["betas"], true["global_orient"][rows], true["body_pose"][rows],
                       true["transl"][rows])[:, 0]
    return float(np.median(np.linalg.norm(fitted - centre, axis=1) / np.linalg.norm(real - centre, axis=1)))


def test_stated_shapes_are_held_and_place_an_adult_and_a_child_at_their_distance(model, tmp_path, monkeypatch):
    """From 2D keypoints alone the adult and the child of adult_child (seed 3) are placed as a pair of the
    prior's mean size, 6-7% off their distance (tests/test_fit_ground.py). Their shapes stated, each keeps
    exactly that shape, each is placed as metrically as a person fitted to 3D keypoints (the floor takes the camera's
height from them), and both stand at their distance."""
    scene_dir = make_scene("adult_child", tmp_path / "adult_child", "small", seed=3)
    keep_only_2d_keypoints(scene_dir)
    truth = scene_dir.with_name(scene_dir.name + ".groundtruth")
    shapes = {}
    for pid in ("p0", "p1"):
        shapes[pid] = dict(np.load(truth / f"{pid}_body.npz"))["betas"]
        np.savez(tmp_path / f"{pid}.npz", betas=shapes[pid])
    scene = load_scene(scene_dir)
    _, _, cameras = read_cameras_json(scene_dir / "cameras.json")
    people = list(scene.humans.values())
    entries = [f"p0={tmp_path / 'p0.npz'}", f"p1={tmp_path / 'p1.npz'}"]

    def fitter(**overrides) -> Fitter:
        return Fitter(scene, BodyModels(model), cameras, _config(**overrides), "metres")

    for overrides, message in (({"person_shapes": [f"p7={tmp_path / 'p0.npz'}"]},
                                r"person_shapes names p7, not among the people fitted \(p0, p1\)"),
                               ({"person_shapes": entries[:1], "ground": {**load_pipeline_yaml()["02_smpl_fit"][
                                   "ground"], "person_heights_m": ["p0=1.8"]}}, "p0 given both a height")):
        checked = fitter(**overrides)
        monkeypatch.setattr(checked, "start", lambda person: pytest.fail("fitted before the statements were checked"))
        with pytest.raises(GlimpseError, match=message):
            checked.fit_people(people)
    fits, floor = fitter(person_shapes=entries).fit_people(people)
    assert "stated shapes): p0, p1" in floor["camera_height_from"], floor
    for fit in fits:
        assert np.array_equal(fit.params.betas, shapes[fit.pid]), fit.pid
        assert fit.report["shape_stated_from"] == str(tmp_path / f"{fit.pid}.npz")
        ratio = _distance_ratio(model, fit.params, dict(np.load(truth / f"{fit.pid}_body.npz")), cameras[0].centre)
        assert ratio == pytest.approx(1.0, abs=0.02), (fit.pid, ratio)
