"""The shared `body` parameters: model path resolution and the scene/model mismatch check."""

import pytest
import yaml

from glimpse.errors import GlimpseError
from glimpse.pipeline.prepare import prepare_run
from tests.scene_builder import build_valid_scene


def set_body_model(scene, kind):
    config = yaml.safe_load((scene / "scene.yaml").read_text())
    config.pop("overrides", None)  # the builder's example overrides name a stage not built yet
    config["body_model"] = kind
    (scene / "scene.yaml").write_text(yaml.safe_dump(config))


def test_scene_parameters_must_belong_to_the_model_in_use(tmp_path):
    scene = tmp_path / "scene"
    build_valid_scene(scene)
    set_body_model(scene, "free")
    prepare_run(scene, tmp_path / "out")  # free scene, free model (the default): fine
    set_body_model(scene, "smpl")
    with pytest.raises(GlimpseError, match=r"scene.yaml: body_model is 'smpl', but body.model_path .* is a 'free' model"):
        prepare_run(scene, tmp_path / "out")


def test_a_missing_model_file_says_what_to_give(tmp_path):
    scene = tmp_path / "scene"
    build_valid_scene(scene)
    set_body_model(scene, "free")
    with pytest.raises(GlimpseError, match=r"body.model_path: no body model file at /nowhere/SMPL_NEUTRAL.pkl"):
        prepare_run(scene, tmp_path / "out", "body.model_path=/nowhere/SMPL_NEUTRAL.pkl")


def test_a_persons_own_model_file_is_checked_like_the_shared_one(tmp_path):
    scene = tmp_path / "scene"
    build_valid_scene(scene)
    set_body_model(scene, "free")
    free = "glimpse/body/assets/free_body.npz"
    prepare_run(scene, tmp_path / "out", f"body.person_model_paths=[p0={free}]")  # the same kind: fine
    with pytest.raises(GlimpseError, match=r"body.person_model_paths \(p1\): no body model file at /nowhere/SMPL_MALE"):
        prepare_run(scene, tmp_path / "out", "body.person_model_paths=[p1=/nowhere/SMPL_MALE.pkl]")
    with pytest.raises(GlimpseError, match=r"'p0' is not PID=PATH"):
        prepare_run(scene, tmp_path / "out", "body.person_model_paths=[p0]")
    with pytest.raises(GlimpseError, match=r"person 'p0' is given twice"):
        prepare_run(scene, tmp_path / "out", f"body.person_model_paths=[p0={free},p0={free}]")
    people = sorted(folder.name for folder in (scene / "humans").iterdir())
    with pytest.raises(GlimpseError, match=rf"names zoe, not a person of .*its people: {', '.join(people)}"):
        prepare_run(scene, tmp_path / "out", f"body.person_model_paths=[zoe={free}]")


def test_a_persons_own_model_of_another_kind_than_the_scenes_parameters_is_refused(tmp_path):
    from tests.body_files import write_random_smpl_pkl

    scene = tmp_path / "scene"
    build_valid_scene(scene)
    set_body_model(scene, "free")
    smpl = write_random_smpl_pkl(tmp_path / "SMPL_MALE.pkl", seed=3, chumpy_style=False)
    with pytest.raises(GlimpseError, match=r"body_model is 'free', but body.person_model_paths \(p1\) .* is a 'smpl'"):
        prepare_run(scene, tmp_path / "out", f"body.person_model_paths=[p1={smpl}]")
