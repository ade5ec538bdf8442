"""The batch runner's parameters (defaults and comments: pipeline.yaml, section batch)."""

from __future__ import annotations

from dataclasses import dataclass, field

from glimpse.errors import ConfigError


@dataclass(frozen=True)
class RayConfig:
    address: str  # the cluster to join ("auto": the one this node belongs to; "": start a local one)
    cpus_per_job: int  # CPUs reserved for each scene (also its compute.threads)
    gpus_per_job: float  # GPUs reserved for each scene
    memory_gb: float  # memory reserved for each scene, GiB (0: none declared)


@dataclass(frozen=True)
class SlurmConfig:
    partition: str  # "" : the cluster's default
    time_min: int  # minutes each job may run before Slurm stops it (it is then requeued and resumes)
    cpus_per_job: int  # CPUs per job (also its compute.threads)
    gpus_per_job: int  # GPUs per job
    mem_gb: float  # memory per job, GiB
    array_parallelism: int  # jobs of the array running at once, at most
    account: str  # "" : none
    qos: str  # "" : none
    setup: list[str] = field(default_factory=list)  # shell lines run before each job (module load, conda activate)


@dataclass(frozen=True)
class BatchConfig:
    jobs: int  # local executor: scenes run at once on this machine (their threads share its cores)
    retries: int  # attempts after the first for a scene that failed or was stopped (each resumes)
    lock_wait_s: float  # seconds a job waits for a run folder another process holds
    ray: RayConfig
    slurm: SlurmConfig

    def __post_init__(self) -> None:
        if self.jobs < 1 or self.retries < 0 or self.lock_wait_s < 0:
            raise ConfigError("pipeline.yaml batch: need jobs >= 1, retries >= 0 and lock_wait_s >= 0, found "
                              f"{self.jobs}, {self.retries} and {self.lock_wait_s}")
        if self.ray.cpus_per_job < 1 or self.slurm.cpus_per_job < 1 or self.slurm.time_min < 1:
            raise ConfigError("pipeline.yaml batch: need ray.cpus_per_job, slurm.cpus_per_job and slurm.time_min "
                              ">= 1")
