"""Before any stage runs: validate the scene, resolve parameters, and write the
per-stage files the Makefile depends on.

Under ``OUT/<scene>/``: ``.dag.mk``, the stage DAG as make variables; and for each stage:
  ``.params/<stage>.json``  its resolved parameters (own section + the shared keys it declares)
  ``.inputs/<stage>.json``  content hashes of the scene files it reads
Both are rewritten only when their content changes, so make reruns exactly the
stages whose parameters or inputs changed, and their descendants.
"""

from __future__ import annotations

import copy
import fnmatch
import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ContextManager

from glimpse.body.config import BodyConfig, check_scene_body_model, person_model_files
from glimpse.config import (
    Params,
    config_from_mapping,
    load_pipeline_yaml,
    parse_cli_params,
    resolve_params,
    safe_load_yaml,
)
from glimpse.errors import ConfigError, GlimpseError, SceneError
from glimpse.locks import exclusive_lock
from glimpse.pipeline.stages import NOT_RESULT_KEYS, STAGES, StageSpec, dag_makefile
from glimpse.scene.runnable import check_runnable

PARAMS_FORMAT = "glimpse-params/1"
INPUTS_FORMAT = "glimpse-inputs/1"
VALIDATION_CACHE_FORMAT = "glimpse-validation-cache/2"
HASH_CACHE_FORMAT = "glimpse-hash-cache/2"
VALIDATOR_HELPERS = ("io/images.py", "config.py")  # files outside glimpse/scene whose code decides a validation
# The environment variable naming a run lock handed down to child processes, and the one saying how long to
# wait for a busy run folder.
RUN_LOCK_ENV = "GLIMPSE_RUN_LOCK"
LOCK_WAIT_ENV = "GLIMPSE_LOCK_WAIT"


@dataclass(frozen=True)
class RunPaths:
    """Where one scene's run lives: ``OUT/<scene name>/``."""

    root: Path

    def stage_dir(self, stage: str) -> Path:
        return self.root / stage

    def manifest(self, stage: str) -> Path:
        return self.root / stage / "manifest.json"

    def params_file(self, stage: str) -> Path:
        return self.root / ".params" / f"{stage}.json"

    def inputs_file(self, stage: str) -> Path:
        return self.root / ".inputs" / f"{stage}.json"

    @property
    def dag_file(self) -> Path:
        """The stage DAG as make variables, included by mk/pipeline.mk."""
        return self.root / ".dag.mk"

    def work_dir(self, stage: str) -> Path:
        return self.root / ".work" / stage

    @property
    def cache_dir(self) -> Path:
        return self.root / ".cache"

    @property
    def lock_file(self) -> Path:
        """Held by whoever runs stages in this folder (``run_lock``)."""
        return self.root / ".lock"


def write_if_changed(path: Path, text: str) -> bool:
    """Write ``text`` to ``path`` atomically unless it already holds exactly that."""
    if path.exists() and path.read_text() == text:
        return False
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)
    return True


def canonical_json(data: Any) -> str:
    return json.dumps(data, indent=2, sort_keys=True) + "\n"


def _scene_files(scene_root: Path) -> list[str]:
    """Every file under the scene, as sorted POSIX paths relative to the root."""
    files = []
    for dirpath, dirnames, filenames in os.walk(scene_root):
        dirnames.sort()
        rel = Path(dirpath).relative_to(scene_root)
        files += [(rel / f).as_posix() for f in filenames]
    return sorted(files)


def _stat_key(path: Path) -> list[int]:
    """What says a file is unchanged without reading it: size, mtime, and the change time and inode, which
    no copy tool can set (``cp -p``, ``rsync -t`` and tar restore mtimes, so size and mtime alone could lie)."""
    st = path.stat()
    return [st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino]


def _code_hash(folder: Path) -> str:
    digest = hashlib.sha256()
    for path in sorted(folder.rglob("*.py")):
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def validate_cached(scene_root: Path, cache_dir: Path) -> None:
    """Validate the scene unless an identical scene (same files, each unchanged by ``_stat_key``)
    already passed with the same validator code; raise SceneError otherwise."""
    from glimpse.scene import validate_scene

    scene_root = scene_root.resolve()
    fingerprint = hashlib.sha256()
    package = Path(__file__).resolve().parent.parent
    fingerprint.update(_code_hash(package / "scene").encode())
    for helper in VALIDATOR_HELPERS:  # the image and YAML readers the validator goes through
        fingerprint.update(hashlib.sha256((package / helper).read_bytes()).hexdigest().encode())
    for rel in _scene_files(scene_root):
        fingerprint.update(f"{rel}:{_stat_key(scene_root / rel)}\n".encode())
    key = hashlib.sha1(str(scene_root).encode()).hexdigest()[:16]
    cache = cache_dir / f"validation-{key}.json"
    expected = {"format": VALIDATION_CACHE_FORMAT, "scene": str(scene_root), "fingerprint": fingerprint.hexdigest()}
    if cache.exists():
        try:
            if json.loads(cache.read_text()) == expected:
                return
        except json.JSONDecodeError:
            pass
    violations = validate_scene(scene_root)
    if violations:
        raise SceneError(str(scene_root), violations)
    write_if_changed(cache, canonical_json(expected))


class HashCache:
    """sha256 of scene files, remembered by ``_stat_key`` so unchanged files are not reread."""

    def __init__(self, path: Path):
        self.path = path
        self.entries: dict[str, Any] = {}
        if path.exists():
            try:
                data = json.loads(path.read_text())
                if data.get("format") == HASH_CACHE_FORMAT:
                    self.entries = data["entries"]
            except (json.JSONDecodeError, KeyError):
                self.entries = {}

    def sha256(self, path: Path) -> str:
        key, stat = str(path.resolve()), _stat_key(path)
        entry = self.entries.get(key)
        if entry and entry[0] == stat:
            return entry[1]
        digest = hashlib.sha256()
        with path.open("rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                digest.update(block)
        self.entries[key] = [stat, digest.hexdigest()]
        return digest.hexdigest()

    def save(self) -> None:
        write_if_changed(self.path, json.dumps({"format": HASH_CACHE_FORMAT, "entries": self.entries}, sort_keys=True))


def scene_input_hashes(scene_root: Path, spec: StageSpec, hashes: HashCache) -> dict[str, str]:
    """Content hashes of the scene files ``spec`` reads (scene.yaml without ``overrides``)."""
    result = {}
    for rel in _scene_files(scene_root):
        if not any(fnmatch.fnmatch(rel, pattern) for pattern in spec.scene_inputs):
            continue
        if rel == "scene.yaml":
            content = safe_load_yaml((scene_root / rel).read_text()) or {}
            content.pop("overrides", None)
            result[rel] = hashlib.sha256(canonical_json(content).encode()).hexdigest()
        else:
            result[rel] = hashes.sha256(scene_root / rel)
    return result


def stage_params(params: Params, spec: StageSpec) -> dict[str, Any]:
    """The parameters one stage's results depend on: its own section whole, and of the shared sections only
    the keys it declares (nested as in pipeline.yaml); never the NOT_RESULT_KEYS."""
    recorded: dict[str, Any] = {}
    for key in spec.reads:
        pattern, *path = key.split(".")
        for section in sorted(fnmatch.filter(params, pattern)):
            source, target = params[section], recorded.setdefault(section, {})
            for part in path[:-1]:
                source, target = source[part], target.setdefault(part, {})
            if path:
                target[path[-1]] = source[path[-1]]
            else:
                recorded[section] = copy.deepcopy(params[section])
    recorded[spec.name] = copy.deepcopy(params.get(spec.name, {}))
    for key in NOT_RESULT_KEYS:
        pattern, *path = key.split(".")
        for section in fnmatch.filter(recorded, pattern):
            parent = recorded[section]
            for part in path[:-1]:
                parent = parent.get(part, {})
            parent.pop(path[-1], None)
    return recorded


def scene_name(scene_root: Path) -> str:
    """The ``name`` from scene.yaml (the scene has been validated)."""
    return str(safe_load_yaml((scene_root / "scene.yaml").read_text())["name"])


def locate_run(scene_root: Path, out_root: Path, whole_pipeline: bool = False, cli_params: str = "") -> RunPaths:
    """Where the scene's run lives, after checking the scene (validated, cached in ``OUT/.cache``) and the
    parameters (resolved with ``cli_params``).

    ``whole_pipeline`` (``make all``): also refuse, with SceneNotRunnable, a valid scene that the pipeline
    cannot run to the end (no people, a person with masks only); one stage alone (``make 01_sfm``) may still run.
    Raises SceneError, SceneNotRunnable or ConfigError before anything under ``out_root`` is touched except
    the cache.
    """
    scene_root = Path(scene_root)
    if not (scene_root / "scene.yaml").is_file():
        from glimpse.errors import Violation

        raise SceneError(str(scene_root), [Violation("scene.yaml", "the scene folder must contain scene.yaml", "no such file")])
    check_writable(Path(out_root))
    validate_cached(scene_root, Path(out_root) / ".cache")
    if whole_pipeline:
        check_runnable(scene_root)
    resolve_scene_params(scene_root, cli_params)
    return RunPaths(Path(out_root) / scene_name(scene_root))


def check_writable(out_root: Path) -> None:
    """GlimpseError, naming the folder, when runs cannot be written under ``out_root``."""
    try:
        out_root.mkdir(parents=True, exist_ok=True)
        probe = out_root / f".write-test-{os.getpid()}"
        probe.touch()
        probe.unlink()
    except OSError as exc:
        raise GlimpseError(f"OUT={out_root}: cannot write runs there ({exc.strerror or exc}); choose another "
                           f"output folder with OUT=... (--out)") from None


def resolve_scene_params(scene_root: Path, cli_params: str) -> Params:
    """Every parameter: pipeline.yaml < the scene's overrides < ``cli_params``; ConfigError when one is
    unknown or invalid, or when the scene's body model and ``body`` disagree."""
    scene_yaml = safe_load_yaml((scene_root / "scene.yaml").read_text()) or {}
    params = resolve_params(load_pipeline_yaml(resolve_auto=False), scene_yaml.get("overrides") or {},
                            parse_cli_params(cli_params),
                            str(scene_root / "scene.yaml"))
    body = config_from_mapping(BodyConfig, params["body"], "body")
    people = sorted(folder.name for folder in scene_root.glob("humans/*") if folder.is_dir())
    strangers = sorted(set(person_model_files(body)) - set(people))
    if strangers:
        raise ConfigError(f"body.person_model_paths names {', '.join(strangers)}, not a person of {scene_root} "
                          f"(its people: {', '.join(people) or 'none'})")
    if any(scene_root.glob("humans/*/smpl.npz")):
        check_scene_body_model(scene_yaml.get("body_model", "free"), body, str(scene_root / "scene.yaml"))
    return params


def run_lock(run: RunPaths, purpose: str, wait_s: float | None = None) -> ContextManager[int]:
    """The run folder's lock (``OUT/<scene>/.lock``), handed down to the processes it starts; ``wait_s``
    (default: $GLIMPSE_LOCK_WAIT, else 0) is how long to wait for another holder before refusing."""
    if wait_s is None:
        wait_s = lock_wait_s()
    return exclusive_lock(run.lock_file, purpose, wait_s, RUN_LOCK_ENV,
                          hint="Wait for it to finish, or ask to wait: make WAIT=<seconds> or --wait <seconds>.")


def lock_wait_s() -> float:
    """Seconds to wait for a busy run folder, from $GLIMPSE_LOCK_WAIT (make WAIT=...); 0 when unset."""
    text = os.environ.get(LOCK_WAIT_ENV, "").strip() or "0"
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not value >= 0:
        raise ConfigError(f"{LOCK_WAIT_ENV} (make WAIT=...) must be a number of seconds >= 0, got {text!r}")
    return value


def prepare_run(scene_root: Path, out_root: Path, cli_params: str = "", whole_pipeline: bool = False
                ) -> tuple[RunPaths, Params]:
    """Check the scene (``locate_run``), resolve and write the .dag.mk and the .params/.inputs files of every
    stage. The caller holds the run's lock (``run_lock``).

    Returns the run's paths and every resolved parameter. Raises SceneError, SceneNotRunnable or ConfigError
    on bad input, before anything under ``out_root`` is touched except the validation cache.
    """
    scene_root = Path(scene_root)
    run = locate_run(scene_root, out_root, whole_pipeline)
    params = resolve_scene_params(scene_root, cli_params)
    hashes = HashCache(run.cache_dir / "hashes.json")
    write_if_changed(run.dag_file, dag_makefile())
    for spec in STAGES:
        write_if_changed(
            run.params_file(spec.name),
            canonical_json({"format": PARAMS_FORMAT, "stage": spec.name, "params": stage_params(params, spec)}),
        )
        write_if_changed(
            run.inputs_file(spec.name),
            canonical_json({"format": INPUTS_FORMAT, "stage": spec.name,
                            "files": scene_input_hashes(scene_root, spec, hashes)}),
        )
    hashes.save()
    return run, params
