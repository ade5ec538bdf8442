"""What the viewer shows of a finished run, and rendering it from any camera: the time, who is hidden,
whether the background is drawn, who is driven by which new motion. No web code here (glimpse.view.server
wires it to the browser); every change bumps ``version`` so that clients know to render again."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from glimpse.cameras.model import PinholeCamera
from glimpse.errors import GlimpseError
from glimpse.humans.person import PersonGaussians
from glimpse.io.images import frame_name, write_png
from glimpse.replay.cameras import mean_up
from glimpse.replay.finished import FinishedRun, default_frame
from glimpse.replay.motion import motion_from_spec, retarget
from glimpse.replay.render import Edits, driven_people, people_centre, render_shot
from glimpse.view.camera import render_size
from glimpse.view.config import ViewConfig

NO_MOTION = "none"


@dataclass
class ViewState:
    """frame_id: the input frame shown (a key of the run's cameras); hidden: pids not drawn; motion: NO_MOTION or
    a motion spec (builtin:NAME or an .npz path) driving ``driven_pid`` from ``frame_id`` (the rest of the scene
    frozen there), at ``motion_index``."""

    frame_id: int
    hidden: set[str] = field(default_factory=set)
    background: bool = True
    motion: str = NO_MOTION
    driven_pid: str = ""
    motion_index: int = 0


class ViewSession:
    """A finished run, the viewer's state, and renders of it. Thread-safe: the browser's events and the render
    loop run in different threads."""

    def __init__(self, run: FinishedRun, config: ViewConfig, device: torch.device):
        if not run.cameras:
            raise GlimpseError(f"{run.folder}: no input camera in 01_sfm/cameras.json: nothing to view")
        self.run, self.config, self.device = run, config, device
        self.frames = sorted(run.cameras)
        self.pids = [p.pid for p in run.people]
        self.state = ViewState(default_frame(run))
        self.version = 0
        self.lock = threading.RLock()
        self._driven: list[PersonGaussians] = []
        self._motion_length = 0

    # --- changes (each bumps the version) ---
    def _changed(self) -> None:
        self.version += 1

    def set_frame(self, frame_id: int) -> None:
        with self.lock:
            if frame_id not in self.run.cameras:
                raise GlimpseError(f"frame {frame_id} is not an input frame with a camera")
            if frame_id != self.state.frame_id:
                self.state.frame_id = frame_id
                if self.state.motion != NO_MOTION:  # the motion starts again from the new time
                    self._drive(self.state.driven_pid, self.state.motion)
                self._changed()

    def set_visible(self, pid: str, visible: bool) -> None:
        with self.lock:
            if pid not in self.pids:
                raise GlimpseError(f"no person {pid!r} in this run (people: {', '.join(self.pids) or 'none'})")
            (self.state.hidden.discard if visible else self.state.hidden.add)(pid)
            self._changed()

    def set_background(self, visible: bool) -> None:
        with self.lock:
            self.state.background = visible
            self._changed()

    def set_motion(self, pid: str, motion: str) -> None:
        """Drive ``pid`` by ``motion`` (builtin:NAME or an .npz path) from the current frame, or stop driving
        (NO_MOTION). GlimpseError when the person has no body at the current frame."""
        with self.lock:
            if motion == NO_MOTION:
                self._driven, self._motion_length = [], 0
                self.state.motion, self.state.driven_pid = NO_MOTION, ""
            else:
                self._drive(pid, motion)
            self._changed()

    def _drive(self, pid: str, motion: str) -> None:
        person = next((p for p in self.run.people if p.pid == pid), None)
        if person is None:
            raise GlimpseError(f"no person {pid!r} in this run (people: {', '.join(self.pids) or 'none'})")
        sequence = motion_from_spec(motion, self.config.motion_fps, self.config.motion_seconds)
        body = retarget(sequence, person.body, self.state.frame_id, self.run.body_models[person.pid],
                        np.arange(len(sequence)))
        self._driven = driven_people(self.run, Edits(driven={pid: body}))
        self._motion_length = len(sequence)
        self.state.motion, self.state.driven_pid, self.state.motion_index = motion, pid, 0

    def step(self) -> None:
        """One frame of playing: the motion's next frame when a person is driven, else the next input frame
        (both wrap around)."""
        with self.lock:
            if self.state.motion != NO_MOTION:
                self.state.motion_index = (self.state.motion_index + 1) % max(1, self._motion_length)
            else:
                position = self.frames.index(self.state.frame_id)
                self.state.frame_id = self.frames[(position + 1) % len(self.frames)]
            self._changed()

    # --- what to look at ---
    def start_camera(self) -> PinholeCamera:
        """The input camera of the frame shown."""
        return self.run.cameras[self.state.frame_id]

    def up(self) -> np.ndarray:
        """(3,) the world's up: the input cameras' mean up."""
        return mean_up(list(self.run.cameras.values()))

    def centre(self) -> np.ndarray:
        """(3,) where the camera orbits: the people's centre at the frame shown, else 3 units in front of the
        input camera."""
        if self.run.people:
            return people_centre(self.run.people, self.state.frame_id)
        camera = self.start_camera()
        return camera.centre + 3.0 * camera.R[2]

    # --- rendering ---
    def render(self, camera: PinholeCamera) -> np.ndarray:
        """[H, W, 3] uint8: the scene as the state says, from ``camera``."""
        with self.lock, torch.no_grad():
            state = self.state
            removed = set(state.hidden) | ({state.driven_pid} if state.motion != NO_MOTION else set())
            edits = Edits(removed=frozenset(removed), background=state.background)
            driven = [p for p in self._driven if p.pid not in state.hidden]
            return render_shot(self.run, camera, state.frame_id, edits, self.device, state.motion_index, driven)

    def screenshot(self, camera: PinholeCamera, folder: Path) -> Path:
        """Render ``camera`` at the still size (its aspect ratio kept) into ``folder`` as
        ``frame_<id>[_<motion>_<index>]_<n>.png`` (n counts up, nothing is overwritten); its path."""
        width, height = render_size(camera.width, camera.height, self.config.still_max_side_px)
        image = self.render(camera.resized(width, height))
        with self.lock:
            stem = f"frame_{frame_name(self.state.frame_id)}"
            if self.state.motion != NO_MOTION:
                motion = Path(self.state.motion.split(":")[-1]).stem
                stem += f"_{self.state.driven_pid}_{motion}_{self.state.motion_index:04d}"
        folder.mkdir(parents=True, exist_ok=True)
        number = 0
        while (folder / f"{stem}_{number}.png").exists():
            number += 1
        path = folder / f"{stem}_{number}.png"
        write_png(path, image)
        return path
