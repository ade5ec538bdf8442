"""The stage registry: what each stage reads (upstream stages, scene files, shared
parameter sections). It is the pipeline's one declaration of the DAG: ``glimpse
prepare`` writes make's prerequisites from ``upstream`` (``make print-dag`` prints them).
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass

from glimpse.errors import GlimpseError


@dataclass(frozen=True)
class StageSpec:
    """One pipeline stage.

    name:          folder name under ``stages/`` and under ``OUT/<scene>/``.
    upstream:      stages whose outputs this one reads (their manifests are make prerequisites).
    reads:         the keys of shared pipeline.yaml sections the stage reads, dotted (``body.skinning``
                   stands for every key under it; a section may be a pattern: ``prior_*`` is every
                   prior's own section). Only these, and the stage's own section, go into
                   its .params file, so a change reruns exactly the stages that read it; the runner
                   refuses to publish a stage that read a shared key it does not declare.
    scene_inputs:  glob patterns, relative to the scene root, of the scene files it reads;
                   ``scene.yaml`` means the file without its ``overrides`` (those are parameters).
    """

    name: str
    upstream: tuple[str, ...]
    reads: tuple[str, ...]
    scene_inputs: tuple[str, ...]

    def declares(self, key: str) -> bool:
        """Whether the dotted shared ``key`` is among (or under) what the stage declares it reads."""
        section, _, path = key.partition(".")
        for declared in self.reads:
            declared_section, _, declared_path = declared.partition(".")
            if fnmatch.fnmatchcase(section, declared_section) and (
                    not declared_path or path == declared_path or path.startswith(declared_path + ".")):
                return True
        return False


_PERSON_2D = ("humans/*/masks/*.png", "humans/*/keypoints2d.npz")
_PERSON_3D = ("humans/*/smpl.npz", "humans/*/keypoints3d.npz")

STAGES: tuple[StageSpec, ...] = (
    StageSpec(
        "01_sfm",
        upstream=(),
        reads=("compute.seed", "compute.threads"),
        scene_inputs=("scene.yaml", "frames/*", "video.mp4", "cameras.json", *_PERSON_2D, *_PERSON_3D),
    ),
    StageSpec(
        "02_smpl_fit",
        upstream=("01_sfm",),
        reads=("compute.seed", "compute.threads", "body.model_path", "body.person_model_paths"),
        scene_inputs=("scene.yaml", *_PERSON_2D, *_PERSON_3D),
    ),
    StageSpec(
        "03_masks",
        upstream=("01_sfm", "02_smpl_fit"),
        reads=("compute.seed", "compute.threads", "body.model_path", "body.person_model_paths"),
        scene_inputs=("humans/*/masks/*.png",),
    ),
    StageSpec(
        "04_bg_pretrain",
        upstream=("01_sfm", "02_smpl_fit", "03_masks"),
        reads=("compute", "render"),
        scene_inputs=(),
    ),
    StageSpec(
        "05_textual_inversion",
        upstream=("01_sfm", "02_smpl_fit", "03_masks"),
        reads=("compute", "body.model_path", "body.person_model_paths", "prior.kind", "diffusion"),
        scene_inputs=("humans/*/reference/*",),
    ),
    StageSpec(
        "06_joint_opt",
        upstream=("01_sfm", "02_smpl_fit", "03_masks", "04_bg_pretrain", "05_textual_inversion"),
        reads=("compute", "body", "render", "prior.kind", "prior_*", "diffusion"),
        scene_inputs=(),
    ),
    StageSpec(
        "07_eval",
        upstream=("01_sfm", "02_smpl_fit", "03_masks", "04_bg_pretrain", "06_joint_opt"),
        reads=("compute", "body.model_path", "body.person_model_paths", "render", "report"),
        scene_inputs=("eval/**/*",),
    ),
)

STAGE_NAMES: tuple[str, ...] = tuple(s.name for s in STAGES)
# Parameters that decide how a stage runs, not what it produces (dotted; the section may be a pattern):
# kept out of the .params stamps, so changing them reruns nothing. Threads change at most float rounding
# (and COLMAP's results when 01_sfm.deterministic is false); checkpoints only where a run may resume; the frame
# cache and the LPIPS features kept with it only what is kept in memory; compute.auto_schedule_scale is already in
# the schedule_scale it resolved.
NOT_RESULT_KEYS: tuple[str, ...] = ("compute.threads", "compute.frame_cache", "compute.frame_read_ahead",
                                     "compute.lpips_target_cache_mb", "compute.auto_schedule_scale",
                                     "*.checkpoint_every")
# The shared sections of pipeline.yaml (patterns): every other section is one stage's own (or, as ingest, one
# command's). report is stage 07's and `glimpse report`'s.
SHARED_SECTIONS: tuple[str, ...] = ("compute", "body", "render", "prior", "prior_*", "diffusion", "report")


def dag_makefile(stages: tuple[StageSpec, ...] = STAGES) -> str:
    """The DAG as make variables (``STAGES``, ``DEPS_<stage>``), for mk/pipeline.mk to include."""
    lines = ["# Written by `glimpse run` from glimpse/pipeline/stages.py, the DAG's one declaration.",
             f"STAGES := {' '.join(spec.name for spec in stages)}"]
    lines += [f"DEPS_{spec.name} := {' '.join(spec.upstream)}".rstrip() for spec in stages]
    return "\n".join(lines) + "\n"


def stage_spec(name: str) -> StageSpec:
    """Look a stage up by name; unknown names list the known ones."""
    for spec in STAGES:
        if spec.name == name:
            return spec
    raise ValueError(f"unknown stage {name!r}; known stages: {', '.join(STAGE_NAMES)}")


def named_stage(name: str) -> StageSpec:
    """``stage_spec`` for a name a user gave (a command-line argument): GlimpseError when unknown."""
    try:
        return stage_spec(name)
    except ValueError as exc:
        raise GlimpseError(str(exc)) from None


if __name__ == "__main__":  # `make print-dag`
    for spec in STAGES:
        print(f"{spec.name}: {' '.join(spec.upstream)}")
