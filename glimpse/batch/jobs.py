"""One scene of a batch: ``glimpse run`` on it in a child process (make runs the stages that are out of
date), retried when it fails or is stopped, each attempt resuming from the stages and checkpoints already
written. Runs the same wherever the executor puts it (a thread here, a Ray worker, a Slurm job): everything it
needs is in the SceneJob, and everything it learns is in the SceneResult and the run folder."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from glimpse.config import STAGE_NAMES, safe_load_yaml
from glimpse.errors import EXIT_BAD_INPUT, EXIT_INTERRUPTED, EXIT_USAGE

VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".avi", ".mkv", ".webm")
LOG_TAIL_LINES = 15  # lines of a failed attempt's output kept in the result
NOT_RETRIED = (EXIT_USAGE, EXIT_BAD_INPUT)  # a wrong command line or bad input fails the same way again
STOPPED_BY_USER = (EXIT_INTERRUPTED, -signal.SIGINT)  # Ctrl-C: not retried (Slurm's SIGTERM/SIGUSR2 are)
STATUSES = ("done", "failed", "bad input", "interrupted")
HEADLINE_KEYS = ("humans_psnr_db", "humans_ssim", "humans_lpips_x100", "seen_psnr_db", "seen_lpips_x100",
                 "never_seen_psnr_db", "never_seen_lpips_x100", "composite_psnr_db")


@dataclass(frozen=True)
class SceneJob:
    """source: a scene folder, or a video (ingested into ``out``/scenes/<stem> first); out: the output root
    (OUT, on storage every worker sees); params: overrides for every stage; threads: compute.threads of the
    job (None: the machine's); attempts: at most this many runs; lock_wait_s: how long to wait for a run
    folder another process holds; python: the interpreter of the environment Glimpse is installed in;
    env: variables added to the job's environment."""

    source: Path
    out: Path
    params: str = ""
    threads: int | None = None
    attempts: int = 3
    lock_wait_s: float = 0.0
    python: str = "python"
    env: dict[str, str] = field(default_factory=dict)

    @property
    def is_video(self) -> bool:
        return self.source.suffix.lower() in VIDEO_SUFFIXES

    @property
    def label(self) -> str:
        return self.source.stem if self.is_video else self.source.name

    @property
    def scene_dir(self) -> Path:
        return self.out / "scenes" / self.label if self.is_video else self.source

    def command(self) -> list[str]:
        """``glimpse run`` for this scene (a video: ingested first unless its scene is up to date)."""
        params = " ".join(p for p in (self.params, f"compute.threads={self.threads}" if self.threads else "") if p)
        command = [self.python, "-m", "glimpse", "run", "--scene", str(self.scene_dir), "--out", str(self.out),
                   "--wait", str(self.lock_wait_s)]
        if self.is_video:
            command += ["--video", str(self.source)]
        return command + (["--params", params] if params else [])


@dataclass
class Attempt:
    """One run of ``glimpse run``: its exit status (negative: stopped by that signal), seconds, the stages it
    (re)ran (their manifests changed) and its output's file."""

    number: int
    exit_code: int
    seconds: float
    stages_run: list[str]
    log: str


@dataclass
class SceneResult:
    """status: done | failed | bad input | interrupted (Ctrl-C); run_dir: OUT/<scene name> (None when no scene
    came to be); headline: stage 07's numbers (HEADLINE_KEYS) when it finished; error: the end of the last
    failed attempt's output."""

    label: str
    source: str
    status: str
    run_dir: str | None
    attempts: list[Attempt]
    seconds: float
    headline: dict[str, float]
    error: str = ""


def run_dir_of(job: SceneJob) -> Path | None:
    """OUT/<name in scene.yaml>, once the scene exists."""
    scene_yaml = job.scene_dir / "scene.yaml"
    if not scene_yaml.is_file():
        return None
    try:
        return job.out / str(safe_load_yaml(scene_yaml.read_text())["name"])
    except (OSError, yaml.YAMLError, KeyError, TypeError):
        return None


def manifest_stamps(run_dir: Path | None) -> dict[str, float]:
    """Stage -> modification time of its manifest (what tells that a stage ran)."""
    if run_dir is None:
        return {}
    stamps = {}
    for stage in STAGE_NAMES:
        manifest = run_dir / stage / "manifest.json"
        if manifest.is_file():
            stamps[stage] = manifest.stat().st_mtime_ns
    return stamps


def headline_of(run_dir: Path | None) -> dict[str, float]:
    """Stage 07's headline numbers from its manifest (empty when it has not finished)."""
    manifest = run_dir / "07_eval" / "manifest.json" if run_dir is not None else None
    if manifest is None or not manifest.is_file():
        return {}
    summary = json.loads(manifest.read_text()).get("summary", {})
    return {key: summary[key] for key in HEADLINE_KEYS if key in summary}


def _tail(path: Path, lines: int) -> str:
    return "\n".join(path.read_text(errors="replace").splitlines()[-lines:]) if path.is_file() else ""


def run_scene(job: SceneJob) -> SceneResult:
    """Run ``job`` until it succeeds, fails on bad input, or has used its attempts; each attempt's output goes
    to OUT/batch_logs/<label>.attempt<N>.log."""
    logs = job.out / "batch_logs"
    logs.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, **job.env}
    attempts: list[Attempt] = []
    started = time.perf_counter()
    status = "failed"
    for number in range(1, job.attempts + 1):
        before = manifest_stamps(run_dir_of(job))
        log = logs / f"{job.label}.attempt{number}.log"
        began = time.perf_counter()
        with log.open("w") as output:
            code = subprocess.run(job.command(), stdout=output, stderr=subprocess.STDOUT, env=env).returncode
        after = manifest_stamps(run_dir_of(job))
        attempts.append(Attempt(number, code, round(time.perf_counter() - began, 1),
                                [s for s in STAGE_NAMES if s in after and after[s] != before.get(s)], str(log)))
        if code == 0:
            status = "done"
            break
        if code in NOT_RETRIED or code in STOPPED_BY_USER:
            status = "bad input" if code in NOT_RETRIED else "interrupted"
            break
    run_dir = run_dir_of(job)
    error = "" if status == "done" else _tail(Path(attempts[-1].log), LOG_TAIL_LINES)
    return SceneResult(job.label, str(job.source), status, str(run_dir) if run_dir else None, attempts,
                       round(time.perf_counter() - started, 1), headline_of(run_dir), error)
