"""schedule_scale: auto becomes compute.auto_schedule_scale's value for the device the stages run on, wherever
parameters are resolved; a number given is kept."""

from __future__ import annotations

import pytest

from glimpse.config import load_pipeline_yaml, parse_cli_params, resolve_auto_schedules, resolve_params
from glimpse.errors import ConfigError

SECTIONS = ("04_bg_pretrain", "06_joint_opt")


def test_the_defaults_leave_schedules_to_the_device():
    raw = load_pipeline_yaml(resolve_auto=False)
    assert all(raw[name]["schedule_scale"] == "auto" for name in SECTIONS)
    assert raw["compute"]["auto_schedule_scale"] == {"cpu": 0.1, "cuda": 1.0}


@pytest.mark.parametrize("device, expected", [("cpu", 0.1), ("cuda", 1.0)])
def test_auto_follows_the_device_the_overrides_choose(device, expected):
    params = resolve_params(load_pipeline_yaml(resolve_auto=False), {"compute": {"device": device}}, [])
    assert all(params[name]["schedule_scale"] == expected for name in SECTIONS)


def test_a_number_is_kept_and_auto_can_be_asked_for_again():
    params = resolve_params(load_pipeline_yaml(resolve_auto=False), {},
                            parse_cli_params("06_joint_opt.schedule_scale=0.25 compute.device=cuda"))
    assert params["06_joint_opt"]["schedule_scale"] == 0.25 and params["04_bg_pretrain"]["schedule_scale"] == 1.0
    params = resolve_params(load_pipeline_yaml(), {},
                            parse_cli_params("06_joint_opt.schedule_scale=auto compute.device=cpu"))
    assert params["06_joint_opt"]["schedule_scale"] == 0.1


def test_auto_without_a_value_for_the_device_is_refused():
    params = load_pipeline_yaml(resolve_auto=False)
    params["compute"]["device"] = "cpu"
    params["compute"]["auto_schedule_scale"] = {"cuda": 1.0}
    with pytest.raises(ConfigError, match="auto_schedule_scale must give a number for cpu"):
        resolve_auto_schedules(params)
