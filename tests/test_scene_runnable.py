"""Scenes valid in form that the pipeline cannot run are refused before any stage, with the fix named."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from glimpse.cli import main
from glimpse.errors import EXIT_BAD_INPUT, SceneNotRunnable
from glimpse.pipeline.prepare import prepare_run
from glimpse.scene import SceneWriter, validate_scene
from glimpse.scene.runnable import runnable_violations


def _scene(root: Path, people: dict[str, tuple[str, ...]]) -> Path:
    """A 3-frame static scene; people: pid -> the kinds of data it gets ("masks", "keypoints2d")."""
    writer = SceneWriter(root, "tiny", 10, "static")
    rng = np.random.default_rng(0)
    for i in range(3):
        writer.frame(i, rng.integers(0, 255, (12, 16, 3), dtype=np.uint8))
    for pid, kinds in people.items():
        if "masks" in kinds:
            for i in range(3):
                writer.person_mask(pid, i, np.eye(12, 16, dtype=bool))
        if "keypoints2d" in kinds:
            writer.keypoints2d(pid, np.arange(3), "coco17", np.full((3, 17, 3), 0.5))
    return writer.finish()


def test_a_scene_with_people_and_keypoints_can_run(tmp_path: Path) -> None:
    root = _scene(tmp_path / "scene", {"p0": ("masks", "keypoints2d")})
    assert validate_scene(root) == [] and runnable_violations(root) == []


def test_a_person_with_masks_only_is_refused_at_prepare(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    root = _scene(tmp_path / "scene", {"p0": ("masks", "keypoints2d"), "p1": ("masks",)})
    assert validate_scene(root) == []  # valid in form
    with pytest.raises(SceneNotRunnable) as caught:
        prepare_run(root, tmp_path / "out", whole_pipeline=True)
    (violation,) = caught.value.violations
    assert violation.file == "humans/p1/" and "masks alone cannot" in violation.rule and violation.found == "only masks/"
    assert "glimpse ingest" in str(caught.value)
    assert not (tmp_path / "out" / "tiny").exists()  # stopped before any stage
    prepare_run(root, tmp_path / "out")  # one stage alone (make 01_sfm) may still run: stage 01 needs only masks
    assert main(["validate", str(root)]) == EXIT_BAD_INPUT
    assert "humans/p1/: a person needs smpl.npz, keypoints2d.npz or keypoints3d.npz" in capsys.readouterr().err


def test_a_scene_without_people_is_refused(tmp_path: Path) -> None:
    root = _scene(tmp_path / "scene", {})
    assert validate_scene(root) == []
    (violation,) = runnable_violations(root)
    assert violation.file == "humans/" and "at least one person" in violation.rule
    (root / "humans").mkdir()
    assert len(runnable_violations(root)) == 1
    with pytest.raises(SceneNotRunnable, match="no person"):
        prepare_run(root, tmp_path / "out", whole_pipeline=True)
