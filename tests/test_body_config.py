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
