"""Where a batch's scenes run: threads of this process (each scene a child process), one Ray task per scene on
an existing cluster, or a Slurm job array through submitit. Each returns the SceneResults in the jobs' order."""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

from glimpse.batch.config import RayConfig, SlurmConfig
from glimpse.batch.jobs import SceneJob, SceneResult, run_scene
from glimpse.errors import GlimpseError

log = logging.getLogger(__name__)
GIB = 2**30
Report = Callable[[SceneResult], None]


def run_local(jobs: Sequence[SceneJob], workers: int, report: Report) -> list[SceneResult]:
    """``workers`` scenes at a time on this machine."""
    results: dict[int, SceneResult] = {}
    pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="glimpse-batch")
    try:
        futures = {pool.submit(run_scene, job): index for index, job in enumerate(jobs)}
        for future in as_completed(futures):
            results[futures[future]] = future.result()
            report(results[futures[future]])
    finally:  # Ctrl-C: scenes not started yet never start; running ones stop with it (their children saw it)
        pool.shutdown(wait=True, cancel_futures=True)
    return [results[index] for index in range(len(jobs))]


def run_ray(jobs: Sequence[SceneJob], config: RayConfig, retries: int, report: Report) -> list[SceneResult]:
    """One Ray task per scene with its resources declared, on the cluster at ``config.address`` (or the one
    this process already joined). A task lost with its node is run again (``retries`` times), resuming."""
    try:
        import ray
    except ImportError:
        raise GlimpseError("--executor ray needs Ray: in the Glimpse checkout, .venv/bin/pip install -c "
                          "constraints.txt -e '.[batch]' (the batch extra of pyproject.toml)") from None
    if not ray.is_initialized():
        ray.init(address=config.address or None, include_dashboard=False, log_to_driver=False)
    options = {"num_cpus": config.cpus_per_job, "num_gpus": config.gpus_per_job, "max_retries": retries}
    if config.memory_gb > 0:
        options["memory"] = int(config.memory_gb * GIB)
    remote = ray.remote(**options)(run_scene)
    pending = {remote.remote(job): index for index, job in enumerate(jobs)}
    results: dict[int, SceneResult] = {}
    while pending:
        done, _ = ray.wait(list(pending), num_returns=1)
        index = pending.pop(done[0])
        results[index] = ray.get(done[0])
        report(results[index])
    return [results[index] for index in range(len(jobs))]


class SceneTask:
    """The callable a Slurm job runs: a scene, resubmitted as it is when Slurm stops the job (time limit,
    pre-emption), which then resumes from its checkpoints (submitit's checkpoint protocol)."""

    def __call__(self, job: SceneJob) -> SceneResult:
        return run_scene(job)

    def checkpoint(self, job: SceneJob):
        import submitit

        return submitit.helpers.DelayedSubmission(self, job)


def slurm_parameters(config: SlurmConfig) -> dict:
    """submitit's parameters for ``config`` (the Slurm ones prefixed slurm_, ignored by other clusters)."""
    parameters = {"timeout_min": config.time_min, "cpus_per_task": config.cpus_per_job,
                  "gpus_per_node": config.gpus_per_job, "mem_gb": config.mem_gb, "tasks_per_node": 1, "nodes": 1,
                  "slurm_array_parallelism": config.array_parallelism, "slurm_setup": list(config.setup),
                  "name": "glimpse"}
    if config.partition:
        parameters["slurm_partition"] = config.partition
    extra = {key: value for key, value in (("account", config.account), ("qos", config.qos)) if value}
    if extra:
        parameters["slurm_additional_parameters"] = extra
    return parameters


def run_slurm(jobs: Sequence[SceneJob], config: SlurmConfig, folder: Path, report: Report,
              cluster: str | None = None) -> list[SceneResult]:
    """One job per scene as a Slurm job array (``cluster`` "local" runs the same submission path on this
    machine, as the tests do); submitit's files and each job's output go to ``folder``."""
    try:
        import submitit
    except ImportError:
        raise GlimpseError("--executor slurm needs submitit: in the Glimpse checkout, .venv/bin/pip install -c "
                          "constraints.txt -e '.[batch]' (the batch extra of pyproject.toml)") from None
    executor = submitit.AutoExecutor(folder=folder, cluster=cluster)
    executor.update_parameters(**slurm_parameters(config))
    submitted = executor.map_array(SceneTask(), list(jobs))
    log.info("submitted %d Slurm job(s): %s", len(submitted), ", ".join(j.job_id for j in submitted))
    results = []
    for job in submitted:
        results.append(job.result())
        report(results[-1])
    return results
