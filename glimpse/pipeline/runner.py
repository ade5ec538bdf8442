"""Running one stage: parse arguments, load inputs, call the stage body, publish
its outputs atomically with a manifest.

A stage holds the run folder's lock (``OUT/<scene>/.lock``, or the one ``glimpse run`` hands down)
and writes every file into ``OUT/<scene>/.tmp/<stage>-<host>-<pid>/``. Only when the
body returns without error is ``manifest.json`` written there (last), and the
folder swapped into ``OUT/<scene>/<stage>/``; the previous output survives any
failure or interruption untouched. Work in progress that should survive a crash
(checkpoints) goes to ``OUT/<scene>/.work/<stage>/``, removed after success.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
import socket
import subprocess
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

from glimpse import __version__
from glimpse.config import config_from_mapping, tracking_reads
from glimpse.errors import EXIT_BAD_INPUT, EXIT_INTERRUPTED, GlimpseError
from glimpse.locks import process_alive
from glimpse.pipeline.prepare import PARAMS_FORMAT, RunPaths, canonical_json, locate_run, prepare_run, run_lock
from glimpse.pipeline.stages import STAGE_NAMES, StageSpec, stage_spec

MANIFEST_FORMAT = "glimpse-manifest/1"
LOG_FILE = "log.txt"  # beside the manifest; a failed stage's is kept as OUT/<scene>/<stage>.failed.log.txt
log = logging.getLogger("glimpse")


@dataclass
class StageContext:
    """Everything a stage body needs.

    out:       the temporary output folder to write into (becomes OUT/<scene>/<stage>/).
    work:      OUT/<scene>/.work/<stage>/ for checkpoints that survive a crash.
    params:    what the output depends on: the stage's own section, and the shared keys it declares
               (its .params file; recorded in the manifest, and what checkpoints are keyed on).
    resolved:  every resolved section, from which ``section`` builds the typed configs.
    reads:     the dotted shared keys the stage has read so far (``section`` logs them).
    formats:   file (relative to ``out``) -> format version; recorded in the manifest.
    timings:   named durations in seconds; recorded in the manifest.
    summary:   small facts for the manifest (mode chosen, counts, errors).
    """

    stage: str
    scene_root: Path
    run: RunPaths
    out: Path
    work: Path
    params: dict[str, Any]
    resolved: dict[str, Any]
    reads: set[str] = field(default_factory=set)
    formats: dict[str, str] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    summary: dict[str, Any] = field(default_factory=dict)

    def section(self, name: str) -> Any:
        """pipeline.yaml section ``name`` (this stage's own or a shared one) as its typed config
        (the class glimpse.pipeline.sections registers for it), built strictly. A shared section logs
        every key read from it in ``reads``."""
        from glimpse.pipeline.sections import SECTION_CONFIGS

        config = config_from_mapping(SECTION_CONFIGS[name], self.resolved[name], f"pipeline.yaml {name}")
        return config if name == self.stage else tracking_reads(config, name, self.reads)

    def upstream_dir(self, stage: str) -> Path:
        """The published output folder of an upstream stage."""
        path = self.run.stage_dir(stage)
        if not (path / "manifest.json").is_file():
            raise GlimpseError(f"stage {self.stage} needs {stage}'s output in {path}; run `make {stage} SCENE=...` first")
        return path

    @contextmanager
    def timed(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.timings[name] = round(self.timings.get(name, 0.0) + time.perf_counter() - start, 4)


def code_version() -> str:
    """glimpse version plus the git commit (``+dirty`` with uncommitted changes)."""
    root = Path(__file__).resolve().parent.parent.parent
    try:
        commit = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "--short=12", "HEAD"], capture_output=True, text=True, timeout=10
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True, text=True, timeout=10,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return __version__
    if not commit:
        return __version__
    return f"{__version__}+{commit}{'.dirty' if dirty else ''}"


def _sha256(path: Path) -> str:
    import hashlib

    return hashlib.sha256(path.read_bytes()).hexdigest()


def _recover_interrupted_swap(final: Path) -> None:
    """If a previous run died between its two renames, put the old output back."""
    for old in final.parent.glob(f".{final.name}.old-*"):
        if not final.exists():
            os.replace(old, final)
        else:
            shutil.rmtree(old, ignore_errors=True)


def publish(tmp: Path, final: Path) -> None:
    """Replace ``final`` by ``tmp``: rename the old folder aside, rename the new in, delete the old."""
    _recover_interrupted_swap(final)
    old = final.parent / f".{final.name}.old-{os.getpid()}"
    if final.exists():
        os.replace(final, old)
    os.replace(tmp, final)
    shutil.rmtree(old, ignore_errors=True)


def _manifest(ctx: StageContext, started: float, upstream: list[str]) -> dict[str, Any]:
    inputs = json.loads(ctx.run.inputs_file(ctx.stage).read_text())
    return {
        "format": MANIFEST_FORMAT,
        "stage": ctx.stage,
        "scene": str(ctx.scene_root.resolve()),
        "code_version": code_version(),
        "formats": dict(sorted(ctx.formats.items())),
        "params": ctx.params,
        "inputs": {
            "upstream_manifests": {s: _sha256(ctx.run.manifest(s)) for s in upstream},
            "scene_files": inputs["files"],
        },
        "timings_s": dict(ctx.timings, total=round(time.time() - started, 4)),
        "summary": ctx.summary,
        "finished_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


def _check_reads(spec: StageSpec, reads: set[str]) -> None:
    """A stage that read a shared key it does not declare would not rerun when that key changes: refuse to
    publish it (a bug in glimpse/pipeline/stages.py, not in the user's input)."""
    undeclared = sorted(key for key in reads if not spec.declares(key))
    if undeclared:
        raise RuntimeError(f"stage {spec.name} read {', '.join(undeclared)}, which its entry in "
                           f"glimpse/pipeline/stages.py does not declare (reads: {', '.join(spec.reads)}); "
                           f"a change to them would not rerun it: declare them there")


def run_stage(stage: str, scene_root: Path, out_root: Path, cli_params: str, body: Callable[[StageContext], None],
              after_publish: Callable[[StageContext], None] | None = None) -> Path:
    """Lock the run folder, prepare, run ``body`` in a temporary folder, publish; return the output folder.
    ``after_publish`` (still under the lock) writes what is made from the published output and lives beside
    the stage folders (stage 07's report.html); ``ctx.out`` no longer exists by then."""
    with run_lock(locate_run(scene_root, out_root, cli_params=cli_params), f"stage {stage}"):
        final, ctx = _run_locked(stage, scene_root, out_root, cli_params, body)
        if after_publish is not None:
            after_publish(ctx)
        return final


def _run_locked(stage: str, scene_root: Path, out_root: Path, cli_params: str, body: Callable[[StageContext], None]
                ) -> tuple[Path, StageContext]:
    spec = stage_spec(stage)
    run, resolved = prepare_run(scene_root, out_root, cli_params)
    params_doc = json.loads(run.params_file(stage).read_text())
    if params_doc.get("format") != PARAMS_FORMAT:
        raise GlimpseError(f"{run.params_file(stage)}: unknown format {params_doc.get('format')!r}; expected {PARAMS_FORMAT}")
    for up in spec.upstream:
        if not run.manifest(up).is_file():
            raise GlimpseError(f"stage {stage} needs {up} first: run `make {stage} SCENE={scene_root}` to build it")
    tmp_root = run.root / ".tmp"
    tmp_root.mkdir(parents=True, exist_ok=True)
    remove_orphans(tmp_root, f"{stage}-")
    tmp = tmp_root / temp_name(stage)
    tmp.mkdir()
    ctx = StageContext(
        stage=stage, scene_root=Path(scene_root), run=run, out=tmp, work=run.work_dir(stage), params=params_doc["params"],
        resolved=resolved,
    )
    started = time.time()
    try:
        with stage_log(tmp / LOG_FILE):
            log.info("%s on %s (glimpse %s), into %s", stage, scene_root, code_version(), run.stage_dir(stage))
            body(ctx)
            _check_reads(spec, ctx.reads)
            ctx.formats[LOG_FILE] = "text: what the stage did, its warnings and timings"
            manifest = _manifest(ctx, started, list(spec.upstream))
            if ctx.summary:
                log.info("summary: %s", json.dumps(ctx.summary, sort_keys=True, default=str))
            log.info("finished in %.1f s (%s)", manifest["timings_s"]["total"],
                     ", ".join(f"{k} {v:.1f} s" for k, v in manifest["timings_s"].items() if k != "total"))
        (tmp / "manifest.json").write_text(canonical_json(manifest))
        publish(tmp, run.stage_dir(stage))
        (run.root / f"{stage}.failed.{LOG_FILE}").unlink(missing_ok=True)
    except BaseException:
        if (tmp / LOG_FILE).is_file():
            shutil.copyfile(tmp / LOG_FILE, run.root / f"{stage}.failed.{LOG_FILE}")
        raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    shutil.rmtree(ctx.work, ignore_errors=True)
    return run.stage_dir(stage), ctx


@contextmanager
def stage_log(path: Path) -> Iterator[None]:
    """While the stage runs, everything Glimpse logs at INFO and above and every Python warning also goes to
    ``path`` (published as the stage's log.txt), each line with its time."""
    handler = logging.FileHandler(path, encoding="utf-8")
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s", "%Y-%m-%d %H:%M:%S"))
    handler.setLevel(logging.INFO)
    package, root = logging.getLogger("glimpse"), logging.getLogger()
    saved_level = package.level
    if package.getEffectiveLevel() > logging.INFO:
        package.setLevel(logging.INFO)
    logging.captureWarnings(True)
    root.addHandler(handler)
    try:
        yield
    except BaseException as exc:  # into the file only: the console gets the stage's own one-line error
        traceback = sys.exc_info() if not isinstance(exc, (GlimpseError, KeyboardInterrupt)) else None
        handler.handle(logging.getLogger(__name__).makeRecord(
            __name__, logging.ERROR, __file__, 0, "stopped: %s", (exc or type(exc).__name__,), traceback))
        raise
    finally:
        root.removeHandler(handler)
        handler.close()
        logging.captureWarnings(False)
        package.setLevel(saved_level)


def temp_name(prefix: str) -> str:
    """A temporary folder's name that says who writes it: ``<prefix>-<host>-<pid>``."""
    return f"{prefix}-{socket.gethostname()}-{os.getpid()}"


def remove_orphans(folder: Path, prefix: str) -> None:
    """Delete the temporary folders ``<prefix><host>-<pid>`` in ``folder`` whose writer is dead: a process
    of this machine that no longer exists, or any process of another machine (the caller holds the run's
    lock, so no other machine can be writing here)."""
    host = socket.gethostname()
    for path in folder.glob(f"{prefix}*"):
        owner_host, _, pid = path.name[len(prefix):].rpartition("-")
        if owner_host == host and pid.isdigit() and process_alive(int(pid)) and int(pid) != os.getpid():
            log.warning("keeping %s: process %s that writes it is still running", path, pid)
            continue
        shutil.rmtree(path, ignore_errors=True)


def stage_main(stage: str, body: Callable[[StageContext], None], description: str,
               after_publish: Callable[[StageContext], None] | None = None) -> None:
    """Command-line entry point of ``stages/<stage>/run.py``.

    Bad input exits with status EXIT_BAD_INPUT and one message, Ctrl-C with EXIT_INTERRUPTED (glimpse.errors;
    what is finished and checkpointed is kept); bugs keep their traceback.
    """
    parser = argparse.ArgumentParser(prog=f"stages/{stage}/run.py", description=description)
    parser.add_argument("--scene", required=True, type=Path, help="scene folder (glimpse-scene/1)")
    parser.add_argument("--out", type=Path, default=Path("runs"), help="output root (default runs/)")
    parser.add_argument(
        "--params", default=os.environ.get("GLIMPSE_PARAMS", ""),
        help='overrides, e.g. "01_sfm.mode=sfm compute.seed=1" (default: $GLIMPSE_PARAMS, set by make PARAMS=...)',
    )
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format=f"[{stage}] %(message)s")
    try:
        final = run_stage(stage, args.scene, args.out, args.params, body, after_publish)
    except GlimpseError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(EXIT_BAD_INPUT)
    except KeyboardInterrupt:
        print(f"{stage}: interrupted; run it again to resume from its last checkpoint", file=sys.stderr)
        sys.exit(EXIT_INTERRUPTED)
    log.info("done: %s", final)


__all__ = ["StageContext", "run_stage", "stage_main", "publish", "STAGE_NAMES", "MANIFEST_FORMAT"]
