"""Synthetic textured box room, seen by a moving camera, with a walking occluder.

A small, deterministic numpy ray-caster used as a test fixture for
structure-from-motion and for everything downstream of it. It renders

* a room: the axis-aligned box ``[-4, 4] x [0, 3] x [-5, 5]`` metres (x right,
  y up, z towards the front wall), whose floor, ceiling and four walls each carry
  their own rich, non-repetitive procedural texture (colour value noise over
  several octaves plus thousands of random sharp-edged shapes drawn with cv2),
  so that SIFT finds many distinctive features on every surface;
* a "person": a textured vertical cylinder (0.56 m wide, 1.7 m tall) that walks
  across the room in front of the camera, against the camera's own motion, so
  that its features are inconsistent with the static scene;

and writes the result as a scene folder in the ``glimpse-scene/1`` input format
(see ``/work/shared/SCENE_FORMAT.md``): ``scene.yaml``, ``frames/000000.png ...``,
``humans/p0/masks/000000.png ...`` and, on request, ``cameras.json``.

Conventions (exactly those of the scene format)
-----------------------------------------------
* Metres; world frame y-up.
* OpenCV pinhole camera: x right, y down, z forward.
* Extrinsics map world to camera: ``x_cam = R @ x_world + t``.
* In ``K`` the centre of the top-left pixel is (0, 0): the ray of pixel
  ``(u, v)`` passes through ``K^-1 [u, v, 1]`` (camera frame).

Rendering
---------
Each pixel is supersampled on a regular ``s x s`` grid (sub-pixel offsets
``(k + 0.5) / s - 0.5``, so the samples are centred on the pixel centre) and the
samples are averaged. Textures are sampled trilinearly from an image pyramid, the
level following the sample's footprint on the surface, so distant and grazing
surfaces do not alias. Shading is view-independent (a constant factor per room
face, Lambertian for the person), so a surface point has the same colour in
every frame, as structure-from-motion expects.

Everything is a pure function of ``seed``: the same call gives byte-identical
PNG files.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from glimpse.fixtures.textures import surface_texture
from glimpse.scene.model import CameraPose
from glimpse.scene.writer import SceneWriter

__all__ = [
    "PERSON_HEIGHT",
    "PERSON_ID",
    "PERSON_RADIUS",
    "PERSON_TEXELS_PER_METRE",
    "ROOM_MAX",
    "ROOM_MIN",
    "Render",
    "RoomRenderer",
    "RoomTruth",
    "camera_poses",
    "get_renderer",
    "intrinsics",
    "make_room_scene",
    "person_positions",
]

#: Room corners, metres, world frame (y up).
ROOM_MIN: np.ndarray = np.array([-4.0, 0.0, -5.0])
ROOM_MAX: np.ndarray = np.array([4.0, 3.0, 5.0])
#: The walking occluder: a vertical cylinder standing on the floor.
PERSON_RADIUS: float = 0.28
PERSON_HEIGHT: float = 1.7
#: Name of the occluder in ``humans/<pid>/``.
PERSON_ID: str = "p0"
#: Frames per second written in scene.yaml.
SCENE_FPS: float = 10.0
#: Texture resolution on the room's surfaces (texels per metre, level 0 of the pyramid).
TEXELS_PER_METRE: float = 160.0
#: Texture resolution on the person, who is seen from much nearer.
PERSON_TEXELS_PER_METRE: float = 480.0

# Surface ids in the hit maps. Room faces are ``2 * axis + (positive side)``.
FACE_X_MIN, FACE_X_MAX, FACE_FLOOR, FACE_CEILING, FACE_Z_MIN, FACE_Z_MAX = range(6)
PERSON_SIDE, PERSON_CAP = 6, 7
N_SURFACES = 8

# For each room face: the two world axes that parametrise it, as (u axis, v axis).
_FACE_AXES: tuple[tuple[int, int], ...] = ((2, 1), (2, 1), (0, 2), (0, 2), (0, 1), (0, 1))
# View-independent brightness of each surface (a fake, fixed illumination).
_FACE_SHADE: tuple[float, ...] = (0.82, 0.90, 0.95, 0.78, 1.0, 0.86)
# Direction towards the light for the person's Lambertian shading (world, unit).
_LIGHT_DIR: np.ndarray = np.array([0.45, 0.75, 0.48]) / np.linalg.norm([0.45, 0.75, 0.48])


# --------------------------------------------------------------------------- truth
@dataclass(frozen=True, eq=False)
class RoomTruth:
    """Ground-truth cameras of a rendered scene.

    Attributes:
        K: (3, 3) intrinsics, pixels; centre of the top-left pixel at (0, 0).
        width: Image width, pixels.
        height: Image height, pixels.
        R: Frame id -> (3, 3) world-to-camera rotation.
        t: Frame id -> (3,) world-to-camera translation, metres
            (``x_cam = R @ x_world + t``).
    """

    K: np.ndarray
    width: int
    height: int
    R: dict[int, np.ndarray]
    t: dict[int, np.ndarray]

    def centres(self) -> dict[int, np.ndarray]:
        """Camera centres in the world frame: frame id -> (3,) ``-R^T t``, metres."""
        return {i: -self.R[i].T @ self.t[i] for i in self.R}


# ------------------------------------------------------------------ camera and path
def intrinsics(width: int, height: int, fov_deg: float = 60.0) -> np.ndarray:
    """Pinhole intrinsics with square pixels and the principal point at the image centre.

    Args:
        width: Image width, pixels.
        height: Image height, pixels.
        fov_deg: Horizontal field of view, degrees (edge to edge of the image).

    Returns:
        (3, 3) ``K`` with ``fx = fy = (width / 2) / tan(fov / 2)`` and
        ``(cx, cy) = ((width - 1) / 2, (height - 1) / 2)`` (pixel centres at integers).
    """
    f = 0.5 * width / math.tan(math.radians(fov_deg) / 2.0)
    return np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


def _look_rotation(forward: np.ndarray, up: np.ndarray = np.array([0.0, 1.0, 0.0])) -> np.ndarray:
    """World-to-camera rotation of an OpenCV camera looking along ``forward`` (world, (3,)).

    Rows are the camera axes in world coordinates: x right, y down (opposite to
    ``up`` as far as possible), z = ``forward``.
    """
    z = forward / np.linalg.norm(forward)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z])


def camera_poses(n_frames: int, camera: str = "moving") -> list[tuple[np.ndarray, np.ndarray]]:
    """Camera path through the room.

    ``"moving"``: over the sequence the centre dollies 2.4 m to the right
    (x from -1.2 to 1.2) along an arc that comes 0.5 m closer to the back wall
    in the middle, at 1.6 m height (+-4 cm bob), while the camera pans 34
    degrees to the left (yaw from 17 degrees right to 17 degrees left of -z),
    pitched 6 degrees down: roughly an orbit around a point 4 m ahead, always
    looking into the room. ``"static"``: the middle pose of that path, every frame.

    Args:
        n_frames: Number of frames (>= 1).
        camera: ``"moving"`` or ``"static"``.

    Returns:
        ``n_frames`` pairs ``(R (3, 3), t (3,))``, world to camera, metres.
    """
    if camera not in ("moving", "static"):
        raise ValueError(f"camera must be 'moving' or 'static', not {camera!r}")
    if n_frames < 1:
        raise ValueError(f"n_frames must be >= 1, not {n_frames}")
    if camera == "static" or n_frames == 1:
        s_all = np.full(n_frames, 0.5)
    else:
        s_all = np.linspace(0.0, 1.0, n_frames)
    poses = []
    pitch = math.radians(-6.0)
    for s in s_all:
        centre = np.array(
            [-1.2 + 2.4 * s, 1.6 + 0.04 * math.sin(2.0 * math.pi * s), 1.5 - 0.5 * math.sin(math.pi * s)]
        )
        yaw = math.radians(-17.0 + 34.0 * s)  # > 0: looking towards -x (left)
        forward = np.array(
            [-math.sin(yaw) * math.cos(pitch), math.sin(pitch), -math.cos(yaw) * math.cos(pitch)]
        )
        R = _look_rotation(forward)
        poses.append((R, -R @ centre))
    return poses


def person_positions(n_frames: int) -> np.ndarray:
    """Where the person stands in each frame.

    The person walks 2.0 m along a slightly diagonal straight line, from
    (x, z) = (1.0, -0.6) to (-1.0, -0.2), i.e. to the left while the moving
    camera goes right, 1.5-2.3 m in front of the camera. With the moving
    camera at 320 x 240 it is in view in every frame and covers 8-27 % of the
    image (at least 15 % in half of the frames).

    Args:
        n_frames: Number of frames (>= 1).

    Returns:
        (n_frames, 2) floor position ``(x, z)`` of the cylinder's axis, metres.
    """
    s = np.linspace(0.0, 1.0, n_frames) if n_frames > 1 else np.array([0.5])
    start, end = np.array([1.0, -0.6]), np.array([-1.0, -0.2])
    return start[None] + s[:, None] * (end - start)[None]


# ------------------------------------------------------------------------ textures
def _pyramid(img: np.ndarray, min_size: int = 4) -> list[np.ndarray]:
    """Gaussian image pyramid, (H, W, 3) uint8 at level 0, halved per level."""
    levels = [img]
    while min(levels[-1].shape[:2]) >= 2 * min_size:
        levels.append(cv2.pyrDown(levels[-1]))
    return levels


def _bilinear(tex: np.ndarray, x: np.ndarray, y: np.ndarray, wrap_x: bool) -> np.ndarray:
    """Bilinear lookup in an (H, W, 3) uint8 image at float texel coordinates.

    Texel ``(i, j)`` has its centre at ``(x, y) = (j, i)``. ``x`` wraps around
    when ``wrap_x``, everything else is clamped to the border.

    Returns:
        (N, 3) float32 colours, 0-255.
    """
    h, w = tex.shape[:2]
    flat = tex.reshape(-1, 3)
    x0f = np.floor(x)
    y0f = np.floor(y)
    fx = (x - x0f).astype(np.float32)[:, None]
    fy = (y - y0f).astype(np.float32)[:, None]
    x0 = x0f.astype(np.int64)
    y0 = y0f.astype(np.int64)
    if wrap_x:
        x0 %= w
        x1 = (x0 + 1) % w
    else:
        x1 = np.clip(x0 + 1, 0, w - 1)
        x0 = np.clip(x0, 0, w - 1)
    y1 = np.clip(y0 + 1, 0, h - 1) * w
    y0 = np.clip(y0, 0, h - 1) * w
    c00 = flat[y0 + x0].astype(np.float32)
    c01 = flat[y0 + x1].astype(np.float32)
    c10 = flat[y1 + x0].astype(np.float32)
    c11 = flat[y1 + x1].astype(np.float32)
    top = c00 + (c01 - c00) * fx
    bottom = c10 + (c11 - c10) * fx
    return top + (bottom - top) * fy


def _trilinear(pyr: list[np.ndarray], u: np.ndarray, v: np.ndarray, lod: np.ndarray,
               wrap_u: bool) -> np.ndarray:
    """Mip-mapped lookup: bilinear in the two pyramid levels around ``lod``, blended.

    Args:
        pyr: Pyramid from :func:`_pyramid`.
        u, v: (N,) level-0 texel coordinates (texel centres at integers).
        lod: (N,) level of detail, log2 of the footprint in level-0 texels.
        wrap_u: Whether ``u`` wraps around (cylinder texture).

    Returns:
        (N, 3) float32 colours, 0-255.
    """
    lod = np.clip(lod, 0.0, len(pyr) - 1.0)
    base = np.floor(lod).astype(np.int64)
    frac = (lod - base).astype(np.float32)[:, None]
    out = np.empty((u.shape[0], 3), np.float32)
    for level in np.unique(base):
        sel = np.flatnonzero(base == level)
        scale = 0.5 ** level
        col = _bilinear(pyr[level], (u[sel] + 0.5) * scale - 0.5, (v[sel] + 0.5) * scale - 0.5, wrap_u)
        if level + 1 < len(pyr):
            scale *= 0.5
            nxt = _bilinear(pyr[level + 1], (u[sel] + 0.5) * scale - 0.5,
                            (v[sel] + 0.5) * scale - 0.5, wrap_u)
            col += (nxt - col) * frac[sel]
        out[sel] = col
    return out


# ----------------------------------------------------------------------- renderer
@dataclass(frozen=True, eq=False)
class Render:
    """One rendered view.

    Attributes:
        image: (H, W, 3) uint8 RGB, supersampled and averaged.
        mask: (H, W) bool, True where the person is the nearest surface for at
            least one of the pixel's sub-samples (every pixel whose colour the
            person contributes to).
        hits: (H, W, 3) float64 world point that the ray through each pixel
            centre hits first, metres; None unless asked for.
        surface: (H, W) int8 id of that surface (``FACE_*``, ``PERSON_SIDE``,
            ``PERSON_CAP``); None unless asked for.
    """

    image: np.ndarray
    mask: np.ndarray
    hits: np.ndarray | None = None
    surface: np.ndarray | None = None


class RoomRenderer:
    """Textured room plus person, ray-cast with numpy.

    Args:
        seed: Seed of every texture; the renderer is a pure function of it.
        texels_per_metre: Texture resolution at pyramid level 0.
    """

    def __init__(self, seed: int = 0, texels_per_metre: float = TEXELS_PER_METRE) -> None:
        self.seed = seed
        self.texels_per_metre = float(texels_per_metre)
        rng = np.random.default_rng(seed)
        extent = ROOM_MAX - ROOM_MIN
        self._pyramids: list[list[np.ndarray]] = []
        for u_axis, v_axis in _FACE_AXES:
            tex = surface_texture(rng, extent[u_axis], extent[v_axis], self.texels_per_metre)
            self._pyramids.append(_pyramid(tex))
        # The person: its own texture (finer shapes, it is seen from nearby),
        # wrapped around the cylinder; the cap gets a small one of its own.
        circumference = 2.0 * math.pi * PERSON_RADIUS
        ptpm = PERSON_TEXELS_PER_METRE
        side = surface_texture(rng, circumference, PERSON_HEIGHT, ptpm,
                                   shapes_per_m2=500.0, min_size_m=0.008, max_size_m=0.3)
        cap = surface_texture(rng, 2 * PERSON_RADIUS, 2 * PERSON_RADIUS, ptpm,
                                  shapes_per_m2=500.0, min_size_m=0.008, max_size_m=0.3)
        self._pyramids.append(_pyramid(side))
        self._pyramids.append(_pyramid(cap))

    # ---------------------------------------------------------------- ray casting
    def cast(self, origin: np.ndarray, dirs: np.ndarray, person_xz: np.ndarray | None
             ) -> tuple[np.ndarray, np.ndarray]:
        """First hit of each ray with the room or the person.

        Args:
            origin: (3,) common ray origin (the camera centre), world, metres;
                must lie inside the room and outside the person.
            dirs: (N, 3) unit ray directions, world.
            person_xz: (2,) floor position of the person's axis, or None for no person.

        Returns:
            ``(dist (N,) float64 metres along the ray, surface (N,) int8 id)``.
        """
        n = dirs.shape[0]
        rows = np.arange(n)
        with np.errstate(divide="ignore", invalid="ignore"):
            bound = np.where(dirs > 0, ROOM_MAX, ROOM_MIN)
            tt = np.where(dirs != 0, (bound - origin) / dirs, np.inf)
        axis = np.argmin(tt, axis=1)
        dist = tt[rows, axis]
        surface = (2 * axis + (dirs[rows, axis] > 0)).astype(np.int8)
        if person_xz is None:
            return dist, surface

        # Vertical cylinder side: |o_xz + s d_xz - c|^2 = r^2, nearer root.
        ox, oz = origin[0] - person_xz[0], origin[2] - person_xz[1]
        dx, dz = dirs[:, 0], dirs[:, 2]
        a = dx * dx + dz * dz
        b = 2.0 * (ox * dx + oz * dz)
        c = ox * ox + oz * oz - PERSON_RADIUS**2
        disc = b * b - 4.0 * a * c
        ok = (disc >= 0) & (a > 1e-12)
        with np.errstate(divide="ignore", invalid="ignore"):
            s_side = np.where(ok, (-b - np.sqrt(np.where(ok, disc, 0.0))) / (2.0 * a), np.inf)
        y_side = origin[1] + s_side * dirs[:, 1]
        s_side = np.where((s_side > 0) & (y_side >= 0.0) & (y_side <= PERSON_HEIGHT), s_side, np.inf)
        # Top cap (seen only from above).
        with np.errstate(divide="ignore", invalid="ignore"):
            s_cap = np.where(dirs[:, 1] < 0, (PERSON_HEIGHT - origin[1]) / dirs[:, 1], np.inf)
        cap_x = ox + s_cap * dx
        cap_z = oz + s_cap * dz
        s_cap = np.where((s_cap > 0) & (cap_x * cap_x + cap_z * cap_z <= PERSON_RADIUS**2), s_cap, np.inf)

        side_first = s_side < dist
        dist = np.where(side_first, s_side, dist)
        surface[side_first] = PERSON_SIDE
        cap_first = s_cap < dist
        dist = np.where(cap_first, s_cap, dist)
        surface[cap_first] = PERSON_CAP
        return dist, surface

    def _shade(self, points: np.ndarray, dirs: np.ndarray, dist: np.ndarray, surface: np.ndarray,
               person_xz: np.ndarray | None, sample_angle: float) -> np.ndarray:
        """Colour of each hit: mip-mapped texture times a view-independent shade.

        Args:
            points: (N, 3) hit points, world, metres.
            dirs: (N, 3) unit ray directions.
            dist: (N,) distances along the rays, metres.
            surface: (N,) surface ids.
            person_xz: (2,) person position or None.
            sample_angle: Angular spacing of the samples, radians.

        Returns:
            (N, 3) float32 RGB, 0-255.
        """
        colour = np.empty((points.shape[0], 3), np.float32)
        for sid in np.unique(surface):
            tpm = self.texels_per_metre if sid < 6 else PERSON_TEXELS_PER_METRE
            sel = np.flatnonzero(surface == sid)
            p = points[sel]
            wrap = False
            if sid < 6:
                u_axis, v_axis = _FACE_AXES[sid]
                u = (p[:, u_axis] - ROOM_MIN[u_axis]) * tpm - 0.5
                v = (ROOM_MAX[v_axis] - p[:, v_axis]) * tpm - 0.5
                cos_inc = np.abs(dirs[sel, sid // 2])
                shade = np.full(sel.shape[0], _FACE_SHADE[sid], np.float32)
            elif sid == PERSON_SIDE:
                assert person_xz is not None
                rx, rz = p[:, 0] - person_xz[0], p[:, 2] - person_xz[1]
                theta = np.arctan2(rz, rx)  # (-pi, pi]
                tex_w = self._pyramids[PERSON_SIDE][0].shape[1]  # one turn, texels
                u = (theta + math.pi) * (tex_w / (2.0 * math.pi)) - 0.5
                v = (PERSON_HEIGHT - p[:, 1]) * tpm - 0.5
                normal = np.stack([rx, np.zeros_like(rx), rz], axis=1) / PERSON_RADIUS
                cos_inc = np.abs(np.einsum("ij,ij->i", dirs[sel], normal))
                shade = (0.55 + 0.45 * np.clip(normal @ _LIGHT_DIR, 0.0, None)).astype(np.float32)
                wrap = True
            else:  # PERSON_CAP
                assert person_xz is not None
                u = (p[:, 0] - person_xz[0] + PERSON_RADIUS) * tpm - 0.5
                v = (p[:, 2] - person_xz[1] + PERSON_RADIUS) * tpm - 0.5
                cos_inc = np.abs(dirs[sel, 1])
                shade = np.full(sel.shape[0], 0.55 + 0.45 * _LIGHT_DIR[1], np.float32)
            # Isotropic footprint: square root of the sample's area on the surface.
            footprint = dist[sel] * sample_angle / np.sqrt(np.maximum(cos_inc, 0.02)) * tpm
            lod = np.log2(np.maximum(footprint, 1e-6))
            colour[sel] = _trilinear(self._pyramids[sid], u, v, lod, wrap) * shade[:, None]
        return colour

    def render(self, K: np.ndarray, R: np.ndarray, t: np.ndarray, width: int, height: int,
               person_xz: np.ndarray | None = None, supersample: int = 2,
               return_hits: bool = False) -> Render:
        """Render one view.

        Args:
            K: (3, 3) intrinsics, pixels (top-left pixel centre at (0, 0)).
            R: (3, 3) world-to-camera rotation.
            t: (3,) world-to-camera translation, metres.
            width: Image width, pixels.
            height: Image height, pixels.
            person_xz: (2,) person position ``(x, z)``, metres, or None for an empty room.
            supersample: Sub-samples per pixel along each axis (>= 1).
            return_hits: Also return the first hit point and surface of the ray
                through each pixel centre.

        Returns:
            The :class:`Render`.
        """
        if supersample < 1:
            raise ValueError(f"supersample must be >= 1, not {supersample}")
        K = np.asarray(K, np.float64)
        R = np.asarray(R, np.float64)
        t = np.asarray(t, np.float64)
        person = None if person_xz is None else np.asarray(person_xz, np.float64)
        centre = -R.T @ t
        ss = int(supersample)
        dirs = self.ray_dirs(K, R, width, height, ss)
        dist, surface = self.cast(centre, dirs, person)
        points = centre + dist[:, None] * dirs
        sample_angle = 1.0 / (ss * 0.5 * (K[0, 0] + K[1, 1]))
        colour = self._shade(points, dirs, dist, surface, person, sample_angle)
        colour = colour.reshape(height, ss, width, ss, 3).mean(axis=(1, 3))
        image = np.clip(np.rint(colour), 0, 255).astype(np.uint8)
        on_person = (surface >= PERSON_SIDE).reshape(height, ss, width, ss)
        mask = on_person.any(axis=(1, 3))
        hits = hit_surface = None
        if return_hits:
            dirs1 = self.ray_dirs(K, R, width, height, 1)
            dist1, hit_surface = self.cast(centre, dirs1, person)
            hits = (centre + dist1[:, None] * dirs1).reshape(height, width, 3)
            hit_surface = hit_surface.reshape(height, width)
        return Render(image=image, mask=mask, hits=hits, surface=hit_surface)

    @staticmethod
    def ray_dirs(K: np.ndarray, R: np.ndarray, width: int, height: int, ss: int) -> np.ndarray:
        """(H*ss*W*ss, 3) unit world directions of the sub-pixel rays, row-major.

        Sub-sample ``(a, b)`` of pixel ``(u, v)`` sits at
        ``(u + (b + 0.5) / ss - 0.5, v + (a + 0.5) / ss - 0.5)``; its ray goes
        through ``K^-1 [x, y, 1]`` in the camera frame.
        """
        offsets = (np.arange(ss) + 0.5) / ss - 0.5
        xs = (np.arange(width)[:, None] + offsets[None, :]).reshape(-1)
        ys = (np.arange(height)[:, None] + offsets[None, :]).reshape(-1)
        gx, gy = np.meshgrid(xs, ys)
        pix = np.stack([gx.ravel(), gy.ravel(), np.ones(gx.size)], axis=1)
        d_cam = pix @ np.linalg.inv(K).T
        d_world = d_cam @ R  # rows of (R^T d_cam)
        return d_world / np.linalg.norm(d_world, axis=1, keepdims=True)


@functools.lru_cache(maxsize=4)
def _renderer(seed: int) -> RoomRenderer:
    """Renderer cache: building the textures is the slow part (about a second)."""
    return RoomRenderer(seed)


def get_renderer(seed: int = 0) -> RoomRenderer:
    """The (cached) :class:`RoomRenderer` for ``seed``."""
    return _renderer(int(seed))


# --------------------------------------------------------------------- scene folder
def make_room_scene(
    out_dir: Path,
    *,
    n_frames: int = 24,
    width: int = 320,
    height: int = 240,
    camera: str = "moving",
    with_person: bool = True,
    with_masks: bool = True,
    write_cameras: str = "none",
    fov_deg: float = 60.0,
    seed: int = 0,
    name: str = "room",
    camera_motion: str | None = None,
    supersample: int = 2,
) -> RoomTruth:
    """Render a sequence and write it as a ``glimpse-scene/1`` folder.

    Writes ``out_dir/scene.yaml`` (``fps: 10``, ``body_model: free``,
    ``camera_motion`` = ``camera`` unless overridden), ``out_dir/frames/NNNNNN.png``
    (8-bit RGB), ``out_dir/humans/p0/masks/NNNNNN.png`` for every frame (0/255,
    single channel, all zero where the person is out of view) when
    ``with_person and with_masks``, and ``out_dir/cameras.json``:
    nothing for ``write_cameras="none"``, ``K``/size only for ``"intrinsics"``,
    ``K``/size and every frame's ``R``/``t`` for ``"poses"``.
    The truth is returned, never written into the scene.

    Args:
        out_dir: Scene folder; created, must not exist or be empty.
        n_frames: Number of frames; ids 0 .. n_frames - 1.
        width: Image width, pixels.
        height: Image height, pixels.
        camera: ``"moving"`` (see :func:`camera_poses`) or ``"static"``.
        with_person: Render the walking occluder.
        with_masks: Write its masks (only with ``with_person``).
        write_cameras: ``"none"``, ``"intrinsics"`` or ``"poses"``.
        fov_deg: Horizontal field of view, degrees.
        seed: Texture seed; same seed, same bytes.
        name: Scene name in scene.yaml.
        camera_motion: Value written as ``camera_motion`` in scene.yaml
            (``"static"``, ``"moving"`` or ``"unknown"``); default: ``camera``.
        supersample: Anti-aliasing sub-samples per pixel along each axis.

    Returns:
        The :class:`RoomTruth` of the rendered cameras.
    """
    if write_cameras not in ("none", "intrinsics", "poses"):
        raise ValueError(f"write_cameras must be 'none', 'intrinsics' or 'poses', not {write_cameras!r}")
    motion = camera if camera_motion is None else camera_motion
    if motion not in ("static", "moving", "unknown"):
        raise ValueError(f"camera_motion must be 'static', 'moving' or 'unknown', not {motion!r}")
    out_dir = Path(out_dir)
    if out_dir.exists() and any(out_dir.iterdir()):
        raise FileExistsError(f"{out_dir} is not empty")
    poses = camera_poses(n_frames, camera)  # validates camera and n_frames
    people = person_positions(n_frames)
    K = intrinsics(width, height, fov_deg)
    renderer = get_renderer(seed)

    scene = SceneWriter(out_dir, name, SCENE_FPS, motion, "free")
    for i, (R, t) in enumerate(poses):
        view = renderer.render(K, R, t, width, height, people[i] if with_person else None, supersample)
        scene.frame(i, view.image)
        if with_person and with_masks:
            scene.person_mask(PERSON_ID, i, view.mask)
    if write_cameras != "none":
        scene.input_cameras(width, height, K, poses={i: CameraPose(R, t) for i, (R, t) in enumerate(poses)}
                            if write_cameras == "poses" else None)
    scene.finish()
    return RoomTruth(K=K, width=width, height=height,
                     R={i: R for i, (R, _) in enumerate(poses)},
                     t={i: t for i, (_, t) in enumerate(poses)})

