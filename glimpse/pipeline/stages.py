"""The stage registry: what each stage reads (upstream stages, scene files, shared
parameter sections) and which issue brings it. The Makefile's DAG mirrors
``upstream`` (``make print-dag`` prints it; a test checks they agree).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class StageSpec:
    """One pipeline stage.

    name:          folder name under ``stages/`` and under ``OUT/<scene>/``.
    upstream:      stages whose outputs this one reads (their manifests are make prerequisites).
    shared:        shared pipeline.yaml sections the stage reads (recorded in its .params file).
    scene_inputs:  glob patterns, relative to the scene root, of the scene files it reads;
                   ``scene.yaml`` means the file without its ``overrides`` (those are parameters).
    issue:         where the stage is built, for the "not implemented yet" message (None = built).
    """

    name: str
    upstream: tuple[str, ...]
    shared: tuple[str, ...]
    scene_inputs: tuple[str, ...]
    issue: str | None = None

    @property
    def implemented(self) -> bool:
        return self.issue is None


_PERSON_2D = ("humans/*/masks/*.png", "humans/*/keypoints2d.npz")
_PERSON_3D = ("humans/*/smpl.npz", "humans/*/keypoints3d.npz")

STAGES: tuple[StageSpec, ...] = (
    StageSpec(
        "01_sfm",
        upstream=(),
        shared=("compute",),
        scene_inputs=("scene.yaml", "frames/*", "video.mp4", "cameras.json", *_PERSON_2D, *_PERSON_3D),
    ),
    StageSpec(
        "02_smpl_fit",
        upstream=("01_sfm",),
        shared=("compute", "body"),
        scene_inputs=("scene.yaml", *_PERSON_2D, *_PERSON_3D),
    ),
    StageSpec(
        "03_masks",
        upstream=("01_sfm", "02_smpl_fit"),
        shared=("compute", "body"),
        scene_inputs=("humans/*/masks/*.png",),
    ),
    StageSpec(
        "04_bg_pretrain",
        upstream=("01_sfm", "02_smpl_fit", "03_masks"),
        shared=("compute", "render"),
        scene_inputs=(),
    ),
    StageSpec(
        "05_textual_inversion",
        upstream=("01_sfm", "02_smpl_fit", "03_masks"),
        shared=("compute", "body", "prior", "diffusion"),
        scene_inputs=("humans/*/reference/*",),
    ),
    StageSpec(
        "06_joint_opt",
        upstream=("01_sfm", "02_smpl_fit", "03_masks", "04_bg_pretrain", "05_textual_inversion"),
        shared=("compute", "body", "render", "prior", "prior_surface", "diffusion"),
        scene_inputs=(),
    ),
    StageSpec(
        "07_eval",
        upstream=("01_sfm", "02_smpl_fit", "03_masks", "04_bg_pretrain", "06_joint_opt"),
        shared=("compute", "body", "render"),
        scene_inputs=("eval/**/*",),
    ),
)

STAGE_NAMES: tuple[str, ...] = tuple(s.name for s in STAGES)
SHARED_SECTIONS: tuple[str, ...] = ("compute", "body", "render", "prior", "prior_surface", "diffusion")


def stage_spec(name: str) -> StageSpec:
    """Look a stage up by name; unknown names list the known ones."""
    for spec in STAGES:
        if spec.name == name:
            return spec
    raise ValueError(f"unknown stage {name!r}; known stages: {', '.join(STAGE_NAMES)}")
