"""User-facing errors: printed as one clear message, never as a traceback."""

from __future__ import annotations

from dataclasses import dataclass


# Exit statuses of `glimpse` and of every stage (README, "Exit statuses"): scripts and schedulers branch on them.
EXIT_STAGE_FAILED = 1  # a stage of `glimpse run` / make failed: its message is above, its finished outputs are kept
EXIT_USAGE = 2  # the command line is wrong (argparse's own status)
EXIT_BAD_INPUT = 3  # a scene, parameter, file or run folder is not what it must be: one message names it and the rule
EXIT_INTERRUPTED = 130  # stopped by Ctrl-C or SIGINT (128 + 2, the shell's convention); rerun to resume


class GlimpseError(Exception):
    """Bad input or a stage that cannot run; the message says what to fix."""


@dataclass(frozen=True)
class Violation:
    """One broken rule of an input file.

    file:  path of the offending file or folder, relative to the scene root
           (e.g. ``cameras.json``, ``humans/p0/masks/000003.png``).
    rule:  the rule, stated as it should hold (e.g. ``R must be a rotation``).
    found: what was found instead (e.g. ``det(R) = -1.0``).
    """

    file: str
    rule: str
    found: str

    def __str__(self) -> str:
        return f"{self.file}: {self.rule}; found {self.found}"


class _SceneViolations(GlimpseError):
    """A scene with problems: "scene ROOT <what> (N problem(s)):", one line per violation, then a hint."""

    what = ""
    hint = ""

    def __init__(self, scene_root: str, violations: list[Violation]):
        self.scene_root = scene_root
        self.violations = list(violations)
        lines = [f"scene {scene_root} {self.what} ({len(self.violations)} problem(s)):"]
        lines += [f"  - {v}" for v in self.violations]
        lines.append(f"  ({self.hint})")
        super().__init__("\n".join(lines))


class SceneError(_SceneViolations):
    """A scene folder breaks the glimpse-scene/1 contract; lists every violation."""

    what = "breaks glimpse-scene/1"
    hint = "see docs/SCENE_FORMAT.md"


class ConfigError(GlimpseError):
    """A parameter is unknown, mistyped or out of range."""


class SceneNotRunnable(_SceneViolations):
    """A scene that is valid glimpse-scene/1 but that the pipeline cannot run; lists what is missing."""

    what = "is valid glimpse-scene/1, but the pipeline cannot run it"
    hint = ("a video with nothing else becomes a scene the pipeline can run with `glimpse ingest VIDEO SCENE_DIR`, "
            "or `make all VIDEO=clip.mp4`; docs/ingest.md")
