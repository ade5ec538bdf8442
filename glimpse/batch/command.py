"""``glimpse batch``: settings (pipeline.yaml's batch section < --params batch.* < a Slurm profile < options),
one SceneJob per source, the chosen executor, and the summary."""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from dataclasses import replace
from pathlib import Path

import yaml

from glimpse.batch.config import BatchConfig
from glimpse.batch.executors import run_local, run_ray, run_slurm
from glimpse.batch.jobs import SceneJob, SceneResult, run_dir_of
from glimpse.batch.summary import write_summary
from glimpse.config import (
    apply_override,
    command_params,
    config_from_mapping,
    safe_load_yaml,
)
from glimpse.errors import EXIT_STAGE_FAILED, GlimpseError

BATCH_PREFIX = "batch."


def batch_settings(params: str, slurm_profile: Path | None) -> tuple[BatchConfig, str]:
    """The batch section with ``batch.*`` overrides and the profile applied; the other overrides, for the
    stages."""
    settings = command_params(params)  # every override checked here, before any job starts
    stage_params = shlex.join(t for t in shlex.split(params or "") if not t.startswith(BATCH_PREFIX))
    if slurm_profile is not None:
        try:
            profile = safe_load_yaml(Path(slurm_profile).read_text()) or {}
        except (OSError, yaml.YAMLError) as exc:
            raise GlimpseError(f"--slurm-profile {slurm_profile}: cannot read it as YAML ({exc})") from None
        if not isinstance(profile, dict):
            raise GlimpseError(f"--slurm-profile {slurm_profile}: must map batch.slurm keys to values")
        for key, value in profile.items():
            apply_override(settings, f"batch.slurm.{key}", value, str(slurm_profile))
    return config_from_mapping(BatchConfig, settings["batch"], "pipeline.yaml batch"), stage_params


def with_options(config: BatchConfig, args: argparse.Namespace) -> BatchConfig:
    """Command-line options over the settings."""
    ray, slurm = config.ray, config.slurm
    if args.cpus_per_job is not None:
        ray, slurm = replace(ray, cpus_per_job=args.cpus_per_job), replace(slurm, cpus_per_job=args.cpus_per_job)
    if args.gpus_per_job is not None:
        ray, slurm = replace(ray, gpus_per_job=args.gpus_per_job), replace(slurm, gpus_per_job=int(args.gpus_per_job))
    if args.ray_address is not None:
        ray = replace(ray, address=args.ray_address)
    slurm = replace(slurm, **{k: v for k, v in (("partition", args.partition), ("time_min", args.time_min))
                              if v is not None})
    changes = {k: v for k, v in (("jobs", args.jobs), ("retries", args.retries)) if v is not None}
    return replace(config, ray=ray, slurm=slurm, **changes)


def scene_jobs(sources: list[Path], out: Path, params: str, threads: int, config: BatchConfig,
               env: dict[str, str]) -> list[SceneJob]:
    """One job per distinct source; a source that is neither a scene folder nor a video is refused, all of them
    named at once."""
    unique = list(dict.fromkeys(Path(s).resolve() for s in sources))
    jobs = [SceneJob(s, Path(out).resolve(), params, threads, config.retries + 1, config.lock_wait_s,
                     sys.executable, env) for s in unique]
    bad = [str(j.source) for j in jobs
           if not ((j.is_video and j.source.is_file()) or (j.source / "scene.yaml").is_file())]
    if bad:
        raise GlimpseError("not a scene folder (no scene.yaml) nor a video: " + ", ".join(bad))
    for names, what in (([j.label for j in jobs], "folder or video name"),
                         ([run.name for j in jobs if (run := run_dir_of(j)) is not None], "scene name")):
        twins = sorted({name for name in names if names.count(name) > 1})
        if twins:
            raise GlimpseError(f"two sources share the {what} {', '.join(twins)}: their scenes or run folders "
                               "would collide; rename one")
    return jobs


def report_line(result: SceneResult) -> None:
    numbers = result.headline.get("humans_psnr_db")
    extra = f", humans PSNR {numbers:.2f} dB" if numbers is not None else ""
    print(f"batch: {result.label}: {result.status} after {len(result.attempts)} attempt(s), {result.seconds:.0f} s"
          f"{extra}", flush=True)


def batch_command(args: argparse.Namespace) -> int:
    config, stage_params = batch_settings(args.params, args.slurm_profile)
    config = with_options(config, args)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    env = {"GOMP_SPINCOUNT": "0"} if args.executor == "local" and config.jobs > 1 else {}
    threads = {"local": max(1, cores // config.jobs), "ray": config.ray.cpus_per_job,
               "slurm": config.slurm.cpus_per_job}[args.executor]
    jobs = scene_jobs(args.sources, args.out, stage_params, threads, config, env)
    args.out.mkdir(parents=True, exist_ok=True)
    print(f"batch: {len(jobs)} scene(s), {args.executor} executor, up to {config.retries + 1} attempt(s) each",
          flush=True)
    if args.executor == "local":
        results = run_local(jobs, config.jobs, report_line)
    elif args.executor == "ray":
        results = run_ray(jobs, config.ray, config.retries, report_line)
    else:
        results = run_slurm(jobs, config.slurm, args.out / "batch_slurm", report_line,
                            cluster=os.environ.get("GLIMPSE_SUBMITIT_CLUSTER") or "slurm")
    json_path, md_path = write_summary(results, args.executor, args.out)
    print(f"batch: summary in {md_path} and {json_path}")
    return 0 if all(r.status == "done" for r in results) else EXIT_STAGE_FAILED

