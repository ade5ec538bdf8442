"""pipeline.yaml, overrides and typed configs."""

import dataclasses
import fnmatch
import re
from typing import Literal

import pytest

from glimpse.config import (
    PIPELINE_YAML, apply_override, config_from_mapping, load_pipeline_yaml, parse_cli_params, resolve_params,
)
from glimpse.errors import ConfigError
from glimpse.pipeline.sections import SECTION_CONFIGS
from glimpse.pipeline.stages import SHARED_SECTIONS, STAGES


def test_every_section_has_a_config_and_every_field_an_entry():
    defaults = load_pipeline_yaml()
    for section, values in defaults.items():
        assert section in SECTION_CONFIGS, f"pipeline.yaml section {section} has no config dataclass"
        cls = SECTION_CONFIGS[section]
        assert set(values) == {f.name for f in dataclasses.fields(cls)}, section
        config_from_mapping(cls, values, f"pipeline.yaml {section}")  # types check out
    assert set(SECTION_CONFIGS) <= set(defaults)


def test_every_parameter_line_has_a_comment():
    for number, line in enumerate(PIPELINE_YAML.read_text().splitlines(), start=1):
        if re.match(r"^\s*[A-Za-z0-9_]+:", line):
            assert "#" in line, f"pipeline.yaml line {number} has no comment: {line!r}"


def test_every_key_a_stage_declares_it_reads_is_a_shared_parameter():
    defaults = load_pipeline_yaml()
    for pattern in SHARED_SECTIONS:
        assert fnmatch.filter(defaults, pattern), pattern
    for spec in STAGES:
        for key in spec.reads:
            pattern, *path = key.split(".")
            assert pattern in SHARED_SECTIONS, (spec.name, key)
            for section in fnmatch.filter(defaults, pattern):
                node = defaults[section]
                for part in path:
                    assert isinstance(node, dict) and part in node, (spec.name, key)
                    node = node[part]


def test_every_prior_owns_a_section_that_stage_06_declares():
    from glimpse.pipeline.sections import SECTION_CONFIGS
    from glimpse.prior import PRIORS

    joint = next(spec for spec in STAGES if spec.name == "06_joint_opt")
    for prior in PRIORS.values():
        if prior.section is not None:
            assert SECTION_CONFIGS[prior.section] is prior.config_class
            assert any(fnmatch.fnmatchcase(prior.section, pattern) for pattern in SHARED_SECTIONS), prior.name
            assert joint.declares(prior.section), prior.name


def test_cli_params_are_parsed_as_yaml():
    assert parse_cli_params('01_sfm.mode=sfm compute.seed=3 01_sfm.fps=null x.y="a b"') == [
        ("01_sfm.mode", "sfm"), ("compute.seed", 3), ("01_sfm.fps", None), ("x.y", "a b"),
    ]
    with pytest.raises(ConfigError, match="expected section.key=value"):
        parse_cli_params("01_sfm.mode")


def test_resolution_order_cli_beats_scene_beats_defaults():
    defaults = {"a": {"k": 1, "j": 2}, "b": {"k": 3}}
    resolved = resolve_params(defaults, {"a": {"k": 10, "j": 20}}, [("a.k", 100)])
    assert resolved == {"a": {"k": 100, "j": 20}, "b": {"k": 3}}
    assert defaults["a"]["k"] == 1  # not mutated


def test_unknown_keys_list_the_known_ones():
    defaults = {"01_sfm": {"mode": "auto", "fps": None}}
    with pytest.raises(ConfigError, match=r"unknown parameter '01_sfm.mdoe'.*known keys of 01_sfm: fps, mode"):
        apply_override(defaults, "01_sfm.mdoe", "sfm", "PARAMS")
    with pytest.raises(ConfigError, match=r"unknown section '02_fit'.*known sections: 01_sfm"):
        apply_override(defaults, "02_fit.x", 1, "PARAMS")
    with pytest.raises(ConfigError, match=r"scene.yaml.*unknown section 'bogus'"):
        resolve_params(defaults, {"bogus": {"x": 1}}, [], "scene.yaml")
    with pytest.raises(ConfigError, match=r"scene.yaml overrides: unknown parameter '01_sfm.nope'"):
        resolve_params(defaults, {"01_sfm": {"nope": 1}}, [], "scene.yaml")


@dataclasses.dataclass(frozen=True)
class _Example:
    mode: Literal["a", "b"]
    rate: float
    count: int
    limit: int | None
    on: bool


@dataclasses.dataclass(frozen=True)
class _Switch:
    switch: Literal["auto", "off"]
    on: bool


def test_typed_config_is_strict():
    good = {"mode": "a", "rate": 1, "count": 2, "limit": None, "on": True}
    cfg = config_from_mapping(_Example, good, "x")
    assert cfg.rate == 1.0 and isinstance(cfg.rate, float)
    for key, bad in [("mode", "c"), ("rate", "fast"), ("count", 1.5), ("count", True), ("on", 1), ("limit", "no")]:
        with pytest.raises(ConfigError, match=rf"x\.{key}: expected"):
            config_from_mapping(_Example, {**good, key: bad}, "x")
    (_, value), = parse_cli_params("x.rate=5e-5")  # YAML 1.1 leaves an exponent without a point a string
    assert value == "5e-5" and config_from_mapping(_Example, {**good, "rate": value}, "x").rate == 5e-5
    assert config_from_mapping(_Example, {**good, "rate": "-1.5E+3"}, "x").rate == -1500.0
    (_, off), = parse_cli_params("x.switch=off")  # YAML 1.1 reads off / on / no / yes as booleans
    assert off is False and config_from_mapping(_Switch, {"switch": off, "on": off}, "x") == _Switch("off", False)
    assert config_from_mapping(_Switch, {"switch": "auto", "on": True}, "x").switch == "auto"
    with pytest.raises(ConfigError, match=r"x\.switch: expected 'auto' \| 'off', found True"):
        config_from_mapping(_Switch, {"switch": True, "on": True}, "x")  # "on" is not one of its words
    with pytest.raises(ConfigError, match=r"x\.count: expected"):
        config_from_mapping(_Example, {**good, "count": "5e2"}, "x")  # only float fields read numbers from text
    with pytest.raises(ConfigError, match="unknown key.*extra.*known keys: count, limit, mode, on, rate"):
        config_from_mapping(_Example, {**good, "extra": 1}, "x")
    with pytest.raises(ConfigError, match="missing key.*rate"):
        config_from_mapping(_Example, {k: v for k, v in good.items() if k != "rate"}, "x")


def test_compute_device_resolves_to_cpu_here_and_refuses_a_missing_cuda():
    import torch

    from glimpse.compute import AutoScheduleScale, ComputeConfig, resolve_device

    schedules = AutoScheduleScale(0.1, 1.0)
    assert resolve_device(ComputeConfig("cpu", 1, 0, 32, 4, 0.0, schedules)) == torch.device("cpu")
    expected = "cuda" if torch.cuda.is_available() else "cpu"
    assert resolve_device(ComputeConfig("auto", 1, 0, 32, 4, 0.0, schedules)).type == expected
    if not torch.cuda.is_available():
        with pytest.raises(ConfigError, match="compute.device is cuda"):
            resolve_device(ComputeConfig("cuda", 1, 0, 32, 4, 0.0, schedules))


def test_the_stage_names_the_report_and_the_batch_read_are_the_pipelines_stages_in_order():
    from glimpse.config import STAGE_NAMES

    assert tuple(spec.name for spec in STAGES) == STAGE_NAMES
