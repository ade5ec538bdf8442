"""What a valid scene still needs before the pipeline can run it: people, each with data stage 02 can place
a body from. Checked by ``glimpse validate`` and at the start of every ``make all`` (``glimpse run``),
so that such a scene stops before any stage instead of failing in stage 02 or 04."""

from __future__ import annotations

from pathlib import Path

from glimpse.errors import SceneNotRunnable, Violation
from glimpse.scene.validate_humans import PERSON_FILES


def runnable_violations(root: str | Path) -> list[Violation]:
    """The reasons a (valid) scene cannot run; empty when it can."""
    humans = Path(root) / "humans"
    persons = sorted(p for p in humans.iterdir() if p.is_dir()) if humans.is_dir() else []
    if not persons:
        return [Violation("humans/", "the pipeline needs at least one person: Glimpse reconstructs people, and with "
                                     "nobody in the scene stages 02-07 have nothing to do", "no person")]
    violations = []
    for person in persons:
        if not any((person / name).is_file() for name in PERSON_FILES):  # what stage 02 places a body from
            found = "only masks/" if (person / "masks").is_dir() else "none of them"
            violations.append(Violation(f"humans/{person.name}/", "a person needs smpl.npz, keypoints2d.npz or "
                                        "keypoints3d.npz: stage 02 places the body from them, masks alone cannot",
                                        found))
    return violations


def check_runnable(root: str | Path) -> None:
    """Raise SceneNotRunnable naming every reason a (valid) scene cannot run."""
    violations = runnable_violations(root)
    if violations:
        raise SceneNotRunnable(str(root), violations)
