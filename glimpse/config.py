"""Parameters: pipeline.yaml defaults, scene overrides, command-line overrides.

Resolution order (later wins):
  1. ``pipeline.yaml`` at the repository root: every parameter with its default;
  2. the scene's ``scene.yaml`` ``overrides`` mapping;
  3. ``PARAMS="section.key=value ..."`` on the command line (values parsed as YAML).

Every override must name a known section and key; unknown ones are errors that
list the known keys. Each stage and each shared part owns a config dataclass
declaring its fields and types (no defaults: defaults live in pipeline.yaml only);
``config_from_mapping`` builds it strictly.
"""

from __future__ import annotations

import dataclasses
import math
import re
import shlex
import types
import typing
from pathlib import Path
from typing import Any, Literal, Mapping

import yaml

from glimpse.errors import ConfigError

REPO_ROOT = Path(__file__).resolve().parent.parent
PIPELINE_YAML = REPO_ROOT / "pipeline.yaml"

Params = dict[str, dict[str, Any]]  # section name -> key -> value
AUTO = "auto"
SCHEDULE_SCALE = "schedule_scale"  # the key, in any section, that scales that section's iteration counts
# The pipeline's stages in order, each the name of its output folder in OUT/<scene>/ (glimpse.pipeline.stages
# declares each one; the report and the batch runner, below the pipeline, read the run folder by these)
STAGE_NAMES = ("01_sfm", "02_smpl_fit", "03_masks", "04_bg_pretrain", "05_textual_inversion", "06_joint_opt",
               "07_eval")
# libyaml's parser when PyYAML was built with it (the wheels are): the same documents, about 15x faster than the
# pure-Python one (pipeline.yaml: 4 ms against 74; every stage process reads it several times)
_HAS_LIBYAML = hasattr(yaml, "CSafeLoader")


def safe_load_yaml(text: str) -> Any:
    """``yaml.safe_load`` of ``text``, with libyaml's safe loader where there is one (raises yaml.YAMLError as
    safe_load does)."""
    return yaml.load(text, Loader=yaml.CSafeLoader if _HAS_LIBYAML else yaml.SafeLoader)


def pipeline_yaml_path() -> Path:
    """The defaults file: $GLIMPSE_PIPELINE_YAML (make PIPELINE_YAML=...) or the repository's pipeline.yaml."""
    import os

    return Path(os.environ.get("GLIMPSE_PIPELINE_YAML") or PIPELINE_YAML)


def load_pipeline_yaml(path: Path | None = None, resolve_auto: bool = True) -> Params:
    """Read pipeline.yaml: a mapping of section name -> mapping of parameters; ``schedule_scale: auto``
    resolved for this machine (:func:`resolve_auto_schedules`) unless ``resolve_auto`` is False (a caller that
    merges overrides first, which may change the device, resolves after them)."""
    path = pipeline_yaml_path() if path is None else path
    try:
        data = safe_load_yaml(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"{path}: cannot read the pipeline parameters: {exc}") from None
    if not isinstance(data, dict) or not all(isinstance(v, dict) for v in data.values()):
        raise ConfigError(f"{path}: must be a mapping of section name -> mapping of parameters")
    if resolve_auto:
        resolve_auto_schedules(data)
    return data


def stage_device_kind(device: str) -> str:
    """"cuda" or "cpu": where stages run for ``compute.device`` (auto: CUDA when torch sees a device)."""
    if device in ("cpu", "cuda"):
        return device
    import torch

    return "cuda" if torch.cuda.is_available() else "cpu"


def resolve_auto_schedules(params: Params) -> None:
    """Replace, in place, every section's ``schedule_scale: auto`` by ``compute.auto_schedule_scale``'s value
    for the device the stages will run on (the paper's full schedule on CUDA, a tenth on a CPU, by default)."""
    sections = [name for name, values in params.items() if values.get(SCHEDULE_SCALE) == AUTO]
    if not sections:
        return
    compute = params.get("compute", {})
    kind = stage_device_kind(str(compute.get("device", AUTO)))
    scales = compute.get("auto_schedule_scale")
    if not isinstance(scales, dict) or not isinstance(scales.get(kind), (int, float)):
        raise ConfigError(f"compute.auto_schedule_scale must give a number for {kind} "
                          f"({', '.join(sections)} have schedule_scale: auto)")
    for name in sections:
        params[name][SCHEDULE_SCALE] = float(scales[kind])


def parse_cli_params(text: str) -> list[tuple[str, Any]]:
    """Parse ``"01_sfm.mode=sfm compute.seed=3"`` into [("01_sfm.mode", "sfm"), ...].

    Values are parsed as YAML (``true``, ``1e-3``, ``[1, 2]``, ``null``); quote a
    value that contains spaces: ``PARAMS='x.name="a b"'``.
    """
    items = []
    for token in shlex.split(text or ""):
        key, sep, raw = token.partition("=")
        if not sep or not key:
            raise ConfigError(f"PARAMS: expected section.key=value, found {token!r}")
        try:
            value = safe_load_yaml(raw) if raw != "" else ""
        except yaml.YAMLError:
            value = raw
        items.append((key.strip(), value))
    return items


def _known(mapping: Mapping[str, Any]) -> str:
    return ", ".join(sorted(mapping)) or "(none)"


def apply_override(params: Params, dotted_key: str, value: Any, source: str) -> None:
    """Set ``section.key[.subkey]`` in ``params`` in place; unknown names are errors."""
    section, _, rest = dotted_key.partition(".")
    if section not in params:
        raise ConfigError(f"{source}: unknown section {section!r} in {dotted_key!r}; known sections: {_known(params)}")
    if not rest:
        raise ConfigError(f"{source}: {dotted_key!r} names a section, not a parameter; use {section}.<key>=value")
    node = params[section]
    parts = rest.split(".")
    for depth, part in enumerate(parts):
        if not isinstance(node, dict) or part not in node:
            where = ".".join([section, *parts[:depth]])
            known = _known(node) if isinstance(node, dict) else "(not a mapping)"
            raise ConfigError(f"{source}: unknown parameter {dotted_key!r}; known keys of {where}: {known}")
        if depth == len(parts) - 1:
            node[part] = value
        else:
            node = node[part]


def _flatten(mapping: Mapping[str, Any], prefix: str) -> list[tuple[str, Any]]:
    items = []
    for key, value in mapping.items():
        if isinstance(value, dict) and value:
            items += _flatten(value, f"{prefix}.{key}")
        else:
            items.append((f"{prefix}.{key}", value))
    return items


def resolve_params(
    defaults: Params,
    scene_overrides: Mapping[str, Any] | None,
    cli_params: list[tuple[str, Any]],
    scene_yaml_name: str = "scene.yaml",
) -> Params:
    """Merge defaults < scene overrides < command line; return a new mapping."""
    import copy

    params = copy.deepcopy(defaults)
    for section, values in (scene_overrides or {}).items():
        if not isinstance(values, dict):
            raise ConfigError(f"{scene_yaml_name}: overrides.{section} must be a mapping of parameters")
        if section not in params:
            raise ConfigError(
                f"{scene_yaml_name}: overrides names unknown section {section!r}; known sections: {_known(params)}"
            )
        for dotted, value in _flatten(values, section):
            apply_override(params, dotted, value, f"{scene_yaml_name} overrides")
    for dotted, value in cli_params:
        apply_override(params, dotted, value, "PARAMS")
    resolve_auto_schedules(params)
    return params


def command_params(cli_params: str) -> Params:
    """pipeline.yaml with ``cli_params`` ("section.key=value ...") applied and no scene: where a command outside
    the stages (ingest, view, batch) reads its own section."""
    return resolve_params(load_pipeline_yaml(resolve_auto=False), None, parse_cli_params(cli_params))


# --------------------------------------------------------------------------- typed configs


def _type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin is Literal:
        return " | ".join(repr(a) for a in typing.get_args(tp))
    if origin in (typing.Union, types.UnionType):
        return " | ".join(_type_name(a) for a in typing.get_args(tp))
    if tp is type(None):
        return "null"
    return getattr(tp, "__name__", str(tp))


def _check_value(value: Any, tp: Any) -> bool:
    origin = typing.get_origin(tp)
    if origin is Literal:
        return value in typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        return any(_check_value(value, a) for a in typing.get_args(tp))
    if tp is type(None):
        return value is None
    if tp is bool:
        return isinstance(value, bool)
    if tp is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if tp is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if tp is str:
        return isinstance(value, str)
    if origin is list:
        (item_tp,) = typing.get_args(tp)
        return isinstance(value, list) and all(_check_value(v, item_tp) for v in value)
    if origin is dict or tp is dict:
        return isinstance(value, dict)
    raise TypeError(f"unsupported config field type {tp!r}")


T = typing.TypeVar("T")
EXPONENT_FLOAT = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)[eE][+-]?\d+")
YAML11_BOOLEAN_WORDS = {True: ("on", "yes", "true"), False: ("off", "no", "false")}  # what YAML 1.1 reads as booleans


def _yaml11_word(value: Any, tp: Any) -> Any:
    """A choice field's word that YAML 1.1 turned into a boolean (``mode: off`` or ``PARAMS=x.mode=off`` reads
    False), given back as the field's choice; any other value unchanged."""
    if not isinstance(value, bool) or typing.get_origin(tp) is not Literal:
        return value
    words = [a for a in typing.get_args(tp) if isinstance(a, str) and a.lower() in YAML11_BOOLEAN_WORDS[value]]
    return words[0] if len(words) == 1 else value


def config_from_mapping(cls: type[T], mapping: Mapping[str, Any], where: str) -> T:
    """Build the config dataclass ``cls`` from ``mapping``, strictly.

    Unknown keys, missing keys and values of the wrong type are ConfigErrors that
    name ``where`` (e.g. ``pipeline.yaml 01_sfm``) and the known keys. Fields that
    are themselves config dataclasses are built recursively. Float fields accept
    integers (converted) and numbers in exponent form that YAML left as strings ("5e-5"); choice fields
    take back the words YAML 1.1 reads as booleans (``off``, ``no``, ``on``, ``yes``).
    """
    if not isinstance(mapping, Mapping):
        raise ConfigError(f"{where}: must be a mapping, found {type(mapping).__name__}")
    hints = typing.get_type_hints(cls)
    fields = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(mapping) - fields)
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)}; known keys: {', '.join(sorted(fields))}")
    missing = sorted(fields - set(mapping))
    if missing:
        raise ConfigError(f"{where}: missing key(s) {', '.join(missing)} (every parameter needs an entry in pipeline.yaml)")
    values = {}
    for name in sorted(fields):
        tp, value = hints[name], mapping[name]
        if dataclasses.is_dataclass(tp):
            values[name] = config_from_mapping(tp, value, f"{where}.{name}")
            continue
        if tp is float and isinstance(value, str) and EXPONENT_FLOAT.fullmatch(value.strip()):
            value = float(value)  # "5e-5": YAML 1.1 reads an exponent without a decimal point as a string
        value = _yaml11_word(value, tp)
        if not _check_value(value, tp):
            raise ConfigError(f"{where}.{name}: expected {_type_name(tp)}, found {value!r}")
        values[name] = float(value) if tp is float else value
    return cls(**values)


def config_to_mapping(config: Any) -> dict[str, Any]:
    """The inverse of config_from_mapping (for manifests and .params files)."""
    return dataclasses.asdict(config)


# --------------------------------------------------------------------------- which keys a stage reads

_READ_LOG = "_glimpse_read_log"  # instance attribute of a tracking copy: (dotted prefix, the set it adds to)
_TRACKING_CLASSES: dict[type, type] = {}


def _tracking_class(cls: type) -> type:
    """A subclass of the config dataclass ``cls`` whose field reads are logged (one class per ``cls``)."""
    if cls not in _TRACKING_CLASSES:
        names = frozenset(f.name for f in dataclasses.fields(cls))

        def __getattribute__(self, name: str) -> Any:
            value = object.__getattribute__(self, name)
            if name in names and not dataclasses.is_dataclass(value):
                try:
                    prefix, reads = object.__getattribute__(self, _READ_LOG)
                except AttributeError:  # a copy made by dataclasses.replace: not tracked
                    return value
                reads.add(f"{prefix}.{name}")
            return value

        _TRACKING_CLASSES[cls] = type(cls.__name__, (cls,), {"__getattribute__": __getattribute__,
                                                             "__qualname__": cls.__qualname__})
    return _TRACKING_CLASSES[cls]


def tracking_reads(config: T, prefix: str, reads: set[str]) -> T:
    """A copy of the config dataclass ``config`` that adds ``prefix.<field>`` (dotted through nested configs) to
    ``reads`` whenever one of its values is read. The runner hands a stage its shared sections this way and
    checks afterwards that the stage declared every key it read (glimpse/pipeline/stages.py). Building the copy
    (whose checks in ``__post_init__`` read every field again) logs nothing."""
    copy = _untracked_copy(config)
    _start_logging(copy, prefix, reads)
    return copy


def _untracked_copy(config: Any) -> Any:
    values = {f.name: getattr(config, f.name) for f in dataclasses.fields(config)}
    values = {name: _untracked_copy(v) if dataclasses.is_dataclass(v) else v for name, v in values.items()}
    return _tracking_class(type(config))(**values)


def _start_logging(copy: Any, prefix: str, reads: set[str]) -> None:
    for f in dataclasses.fields(copy):
        value = object.__getattribute__(copy, f.name)
        if dataclasses.is_dataclass(value):
            _start_logging(value, f"{prefix}.{f.name}", reads)
    object.__setattr__(copy, _READ_LOG, (prefix, reads))
