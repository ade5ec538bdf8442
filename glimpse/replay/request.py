"""What ``glimpse render`` was asked for, from its command-line strings: times and a camera path.

Times: ``T`` (one input frame id), ``A:B`` (the input frames with a camera from A to B), ``all``.
Cameras: ``input`` (the input camera of each time), ``orbit`` or ``orbit:DEGREES`` (turning the input
camera of the first time about the people), ``heldout:NAME`` (a held-out camera of the scene given
with ``--scene``), ``json:FILE`` (a Glimpse cameras.json), ``colmap:FOLDER`` (a COLMAP model).
"""

from __future__ import annotations

from pathlib import Path

from glimpse.cameras.model import PinholeCamera
from glimpse.errors import GlimpseError
from glimpse.replay.cameras import colmap_path, json_path, mean_up, orbit_path
from glimpse.replay.finished import FinishedRun
from glimpse.replay.render import people_centre

CAMERA_KINDS = ("input", "orbit", "heldout", "json", "colmap")


def parse_times(spec: str, run: FinishedRun, option: str = "--time") -> list[int]:
    """Input frame ids (with a camera) named by ``spec`` (the command-line ``option`` that gave it)."""
    frames = sorted(run.cameras)
    if spec == "all":
        return frames
    try:
        if ":" in spec:
            first, last = (int(part) for part in spec.split(":", 1))
            chosen = [f for f in frames if first <= f <= last]
        else:
            chosen = [int(spec)] if int(spec) in run.cameras else []
    except ValueError:
        raise GlimpseError(f"{option} {spec!r}: give a frame id T, a range A:B, or all") from None
    if not chosen:
        raise GlimpseError(f"{option} {spec}: no input frame with a camera there (frames {frames[0]}..{frames[-1]})")
    return chosen


def camera_shots(spec: str, run: FinishedRun, times: list[int], orbit_frames: int, scene: Path | None
                 ) -> list[PinholeCamera]:
    """The camera path named by ``spec`` (see the module's docstring)."""
    kind, _, argument = spec.partition(":")
    if kind == "input":
        return [run.cameras[t] for t in times]
    if kind == "orbit":
        degrees = float(argument) if argument else 360.0
        count = len(times) if len(times) > 1 else orbit_frames
        return orbit_path(run.cameras[times[0]], people_centre(run.people, times[0]),
                          mean_up(list(run.cameras.values())), count, degrees)
    if kind == "heldout":
        return heldout_shots(scene, argument, times)
    if kind == "json":
        return json_path(Path(argument))
    if kind == "colmap":
        return colmap_path(Path(argument))
    raise GlimpseError(f"--camera {spec!r}: the kinds are {', '.join(CAMERA_KINDS)}")


def heldout_shots(scene: Path | None, name: str, times: list[int]) -> list[PinholeCamera]:
    """A held-out camera of the scene's eval/: its pose at each time where it moves, else its one pose."""
    from glimpse.scene import load_scene

    if scene is None:
        raise GlimpseError("--camera heldout:NAME needs --scene SCENE (the run's scene folder, for its eval/)")
    cameras = load_scene(scene).eval_cameras
    if name not in cameras:
        raise GlimpseError(f"{scene / 'eval'}: no held-out camera {name!r} (there are: "
                           f"{', '.join(sorted(cameras)) or 'none'})")
    cam = cameras[name]
    shots = [cam.camera_at(t) for t in times]
    return shots if any(cam.poses.get(t) for t in times) else shots[:1]
