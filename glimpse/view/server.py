"""The viewer's web side (viser): the page, its controls, and a render loop that draws the scene from each
browser's camera with Glimpse's rasterizer and sends it as the page's background image (as nerfstudio's
viewer does). Renders are small while the camera moves and sharp once it rests."""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from glimpse.body.motion import BUILTIN_MOTIONS
from glimpse.errors import GlimpseError
from glimpse.view.camera import pinhole_from_viewer, render_size, viewer_from_pinhole
from glimpse.view.session import NO_MOTION, ViewSession

log = logging.getLogger(__name__)
IDLE_WAIT_S = 0.01  # seconds the render loop sleeps when no client needs a frame
FRUSTUM_SCALE = 0.15  # world units: size of the input cameras' frustums


@dataclass
class ClientView:
    """What was last sent to one browser: the camera and scene version it showed, and whether sharp."""

    key: tuple = ()
    sharp: bool = False
    moved_at: float = 0.0
    frames_sent: int = 0
    last_size: tuple[int, int] = (0, 0)


class ViewerServer:
    """Serves ``session`` at http://host:port until ``stop``; screenshots go to ``screenshot_dir``."""

    def __init__(self, session: ViewSession, screenshot_dir: Path, host: str, port: int,
                 motions: tuple[str, ...] = ()):
        import viser

        self.session, self.screenshot_dir = session, screenshot_dir
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.views: dict[int, ClientView] = {}
        self.screenshots: list[Path] = []
        self._stop = threading.Event()
        self.server.scene.set_up_direction(tuple(float(v) for v in session.up()))
        self._add_cameras()
        self._add_controls(tuple(f"builtin:{name}" for name in BUILTIN_MOTIONS) + tuple(motions))
        self.server.on_client_connect(self._connected)
        self.server.on_client_disconnect(lambda client: self.views.pop(client.client_id, None))
        self._thread = threading.Thread(target=self._render_loop, name="glimpse-view-render", daemon=True)
        self._thread.start()

    @property
    def port(self) -> int:
        return self.server.get_port()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10)
        self.server.stop()

    # --- the page ---
    def _add_cameras(self) -> None:
        """A frustum per input camera pose (one for a static camera)."""
        shown: list = []
        for frame_id, camera in sorted(self.session.run.cameras.items()):
            if shown and np.allclose(camera.R, shown[-1].R) and np.allclose(camera.t, shown[-1].t):
                continue
            shown.append(camera)
            wxyz, position, fov_y = viewer_from_pinhole(camera)
            self.server.scene.add_camera_frustum(f"/input_cameras/{frame_id}", fov_y, camera.width / camera.height,
                                                 scale=FRUSTUM_SCALE, wxyz=wxyz, position=position)

    def _add_controls(self, motions: tuple[str, ...]) -> None:
        gui, session = self.server.gui, self.session
        frames = session.frames
        self.time = gui.add_slider("input frame", 0, len(frames) - 1, 1, frames.index(session.state.frame_id),
                                   hint="the time shown: an input frame")
        self.time.on_update(lambda _: self._guarded(lambda: session.set_frame(frames[int(self.time.value)])))
        self.play = gui.add_checkbox("play", False, hint="advance the input frames (or the motion)")
        with gui.add_folder("show"):
            self.shown = {pid: gui.add_checkbox(pid, True) for pid in session.pids}
            for pid, box in self.shown.items():
                box.on_update(lambda _, pid=pid, box=box: self._guarded(lambda: session.set_visible(pid, box.value)))
            self.background = gui.add_checkbox("background", True)
            self.background.on_update(lambda _: self._guarded(lambda: session.set_background(self.background.value)))
        with gui.add_folder("new motion"):
            self.driven = gui.add_dropdown("person", tuple(session.pids) or ("nobody",))
            self.motion = gui.add_dropdown("motion", (NO_MOTION,) + motions, initial_value=NO_MOTION,
                                           hint="drive the person from the frame shown; the rest stays frozen")
            update = lambda _: self._guarded(lambda: session.set_motion(self.driven.value, self.motion.value))  # noqa: E731
            self.motion.on_update(update)
            self.driven.on_update(update)
        self.snap = gui.add_button("save screenshot", hint=f"a sharp render into {self.screenshot_dir}")
        self.snap.on_click(self._screenshot)

    def _guarded(self, change) -> None:
        """Apply a change from the page; a GlimpseError (e.g. a person absent at that frame) is shown to every
        browser instead of raised in viser's thread."""
        try:
            change()
        except GlimpseError as exc:
            for client in self.server.get_clients().values():
                client.add_notification("Glimpse", str(exc), auto_close_seconds=8.0, color="red")

    def _connected(self, client) -> None:
        """Start a new browser at the input camera of the frame shown, orbiting the people."""
        wxyz, position, fov_y = viewer_from_pinhole(self.session.start_camera())
        with client.atomic():
            client.camera.up_direction = tuple(float(v) for v in self.session.up())
            client.camera.position = position
            client.camera.look_at = self.session.centre()
            client.camera.fov = fov_y
        self.views[client.client_id] = ClientView()

    def _camera_of(self, client, max_side: int):
        camera = client.camera
        width, height = render_size(camera.image_width, camera.image_height, max_side)
        return pinhole_from_viewer(camera.wxyz, camera.position, camera.fov, width, height)

    def _screenshot(self, event) -> None:
        client = event.client
        if client is None:
            return
        path = self.session.screenshot(self._camera_of(client, self.session.config.still_max_side_px),
                                       self.screenshot_dir)
        self.screenshots.append(path)
        client.add_notification("Screenshot saved", str(path), auto_close_seconds=6.0)
        log.info("screenshot: %s", path)

    # --- rendering ---
    def _render_loop(self) -> None:
        config, last_step = self.session.config, time.perf_counter()
        while not self._stop.is_set():
            if self.play.value and time.perf_counter() - last_step >= 1.0 / config.play_fps:
                last_step = time.perf_counter()
                self.session.step()
                if self.session.state.motion == NO_MOTION:
                    self.time.value = self.session.frames.index(self.session.state.frame_id)
            sent = False
            for client in list(self.server.get_clients().values()):
                try:
                    sent |= self._refresh(client)
                except Exception:  # a browser that went away mid-frame, or a bug: keep serving the others
                    log.exception("viewer: rendering for client %s failed", client.client_id)
            if not sent:
                self._stop.wait(IDLE_WAIT_S)

    def _refresh(self, client) -> bool:
        """Render for ``client`` when its camera or the scene changed (small), or sharp once the camera has
        rested; True when a frame was sent."""
        view = self.views.get(client.client_id)
        camera = client.camera
        if view is None or camera.update_timestamp == 0.0 or camera.image_height <= 0:
            return False
        key = (tuple(np.round(camera.wxyz, 6)), tuple(np.round(camera.position, 6)), round(camera.fov, 6),
               camera.image_width, camera.image_height, self.session.version)
        now, config = time.perf_counter(), self.session.config
        if key != view.key:
            view.key, view.sharp, view.moved_at = key, False, now
            sharp = False
        elif not view.sharp and not self.play.value and now - view.moved_at >= config.sharp_after_s:
            sharp = True
        else:
            return False
        image = self.session.render(self._camera_of(client, config.still_max_side_px if sharp
                                                    else config.preview_max_side_px))
        client.scene.set_background_image(image, format="jpeg", jpeg_quality=config.jpeg_quality)
        view.frames_sent, view.last_size = view.frames_sent + 1, (image.shape[1], image.shape[0])
        view.sharp = sharp or view.sharp
        return True
