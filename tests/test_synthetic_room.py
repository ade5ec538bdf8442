"""Self-checks of the synthetic room fixture (tests/support/synthetic_room.py).

Fast (a few seconds, mostly building one set of textures twice): determinism,
the camera/pixel convention, the person masks and the scene-folder layout.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from tests.support import synthetic_room as sr  # tests/conftest.py puts the repository root on sys.path

SEED = 3  # one seed for the whole module, so the texture cache is built once more at most
W, H = 80, 60


def _project(K: np.ndarray, R: np.ndarray, t: np.ndarray, X: np.ndarray) -> np.ndarray:
    """(..., 3) world points -> (..., 2) pixels, written out independently of the renderer."""
    x_cam = X @ R.T + t
    assert np.all(x_cam[..., 2] > 0)
    uvw = x_cam @ K.T
    return uvw[..., :2] / uvw[..., 2:3]


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_same_seed_same_bytes(tmp_path: Path) -> None:
    kwargs = dict(n_frames=3, width=W, height=H, seed=SEED, write_cameras="poses")
    sr._renderer.cache_clear()
    sr.make_room_scene(tmp_path / "a", **kwargs)
    sr._renderer.cache_clear()  # rebuild the textures from the seed
    sr.make_room_scene(tmp_path / "b", **kwargs)
    a, b = _files(tmp_path / "a"), _files(tmp_path / "b")
    assert sorted(a) == sorted(b)
    assert any(k.startswith("frames/") for k in a) and any(k.startswith("humans/p0/masks/") for k in a)
    assert a == b
    sr.make_room_scene(tmp_path / "c", **{**kwargs, "seed": SEED + 1})
    assert _files(tmp_path / "c")["frames/000000.png"] != a["frames/000000.png"]


@pytest.mark.parametrize("frame", [0, 7, 15])
def test_pixel_convention(frame: int) -> None:
    """The point the renderer draws at pixel (u, v) projects back to (u, v) through K, R, t."""
    renderer = sr.get_renderer(SEED)
    K = sr.intrinsics(W, H, 60.0)
    R, t = sr.camera_poses(16)[frame]
    view = renderer.render(K, R, t, W, H, sr.person_positions(16)[frame], return_hits=True)
    assert view.hits is not None and view.surface is not None
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    uv = _project(K, R, t, view.hits)
    np.testing.assert_allclose(uv[..., 0], u, atol=1e-6, rtol=0)
    np.testing.assert_allclose(uv[..., 1], v, atol=1e-6, rtol=0)

    # The hits lie on the surfaces they claim: a box face, or the person's side.
    room = view.surface < sr.PERSON_SIDE
    axis, positive = view.surface[room] // 2, view.surface[room] % 2 == 1
    bound = np.where(positive, sr.ROOM_MAX[axis], sr.ROOM_MIN[axis])
    np.testing.assert_allclose(view.hits[room][np.arange(axis.size), axis], bound, atol=1e-9)
    assert np.all(view.hits >= sr.ROOM_MIN - 1e-9) and np.all(view.hits <= sr.ROOM_MAX + 1e-9)

    # The anti-aliasing sub-samples are centred on the pixel centres.
    ss = 2
    d = sr.RoomRenderer.ray_dirs(K, R, W, H, ss)
    sub_uv = _project(K, R, t, -R.T @ t + d).reshape(H, ss, W, ss, 2).mean(axis=(1, 3))
    np.testing.assert_allclose(sub_uv[..., 0], u, atol=1e-9, rtol=0)
    np.testing.assert_allclose(sub_uv[..., 1], v, atol=1e-9, rtol=0)


def test_images_agree_with_truth_across_frames() -> None:
    """Warping frame j into frame i with the true geometry reproduces frame i (static parts)."""
    renderer = sr.get_renderer(SEED)
    w, h = 160, 120
    K = sr.intrinsics(w, h, 60.0)
    poses = sr.camera_poses(24)
    (Ri, ti), (Rj, tj) = poses[10], poses[12]
    vi = renderer.render(K, Ri, ti, w, h, None, return_hits=True)
    vj = renderer.render(K, Rj, tj, w, h, None)
    assert vi.hits is not None
    uv = _project(K, Rj, tj, vi.hits).astype(np.float32)
    inside = (uv[..., 0] > 2) & (uv[..., 0] < w - 3) & (uv[..., 1] > 2) & (uv[..., 1] < h - 3)
    assert inside.mean() > 0.7

    def residual(shift: float) -> float:
        warped = cv2.remap(vj.image.astype(np.float32), uv[..., 0] + shift, uv[..., 1], cv2.INTER_LINEAR)
        return float(np.abs(warped - vi.image.astype(np.float32))[inside].mean())

    good = residual(0.0)
    assert good < 0.5 * residual(1.0)  # a one-pixel error would be clearly visible
    assert good < 10.0


def test_masks_are_the_person_nearest_pixels(tmp_path: Path) -> None:
    renderer = sr.get_renderer(SEED)
    n = 8
    truth = sr.make_room_scene(tmp_path / "s", n_frames=n, width=W, height=H, seed=SEED)
    people = sr.person_positions(n)
    covered = 0
    for i in range(n):
        written = cv2.imread(str(tmp_path / "s" / "humans" / "p0" / "masks" / f"{i:06d}.png"),
                             cv2.IMREAD_UNCHANGED)
        assert written.dtype == np.uint8 and written.shape == (H, W)
        assert set(np.unique(written)) <= {0, 255}
        view = renderer.render(truth.K, truth.R[i], truth.t[i], W, H, people[i], return_hits=True)
        np.testing.assert_array_equal(written == 255, view.mask)

        # At pixel centres: the mask is where the person is the nearest surface.
        centre_view = renderer.render(truth.K, truth.R[i], truth.t[i], W, H, people[i],
                                      supersample=1, return_hits=True)
        assert centre_view.hits is not None and centre_view.surface is not None
        on_person = centre_view.surface >= sr.PERSON_SIDE
        np.testing.assert_array_equal(centre_view.mask, on_person)
        assert np.all(view.mask[on_person])  # any-sub-sample mask covers the centre mask
        covered += int(on_person.sum())
        # Person pixels hit the cylinder; every other pixel's ray reaches the room
        # without passing through it (checked by sampling the segments).
        rx = centre_view.hits[..., 0] - people[i][0]
        rz = centre_view.hits[..., 2] - people[i][1]
        radius = np.hypot(rx, rz)[on_person]
        np.testing.assert_allclose(radius, sr.PERSON_RADIUS, atol=1e-9)
        centre = truth.centres()[i]
        seg = centre + np.linspace(0.0, 1.0, 400)[:, None, None] * (centre_view.hits[~on_person] - centre)
        inside = ((np.hypot(seg[..., 0] - people[i][0], seg[..., 2] - people[i][1]) < sr.PERSON_RADIUS - 1e-6)
                  & (seg[..., 1] > 0) & (seg[..., 1] < sr.PERSON_HEIGHT))
        assert not inside.any()
    assert covered > 0.1 * n * W * H  # the person really is in the way


def test_scene_layout(tmp_path: Path) -> None:
    truth = sr.make_room_scene(tmp_path / "m", n_frames=2, width=W, height=H, seed=SEED,
                               write_cameras="poses", name="walk")
    scene = yaml.safe_load((tmp_path / "m" / "scene.yaml").read_text())
    assert scene == {"format": "glimpse-scene/1", "name": "walk", "fps": 10,
                     "camera_motion": "moving", "body_model": "free"}
    cams = json.loads((tmp_path / "m" / "cameras.json").read_text())
    assert cams["format"] == "glimpse-cameras/1" and (cams["width"], cams["height"]) == (W, H)
    np.testing.assert_allclose(cams["K"], truth.K)
    assert sorted(cams["frames"]) == ["000000", "000001"]
    for i in range(2):
        R = np.array(cams["frames"][f"{i:06d}"]["R"])
        np.testing.assert_allclose(R, truth.R[i])
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
        np.testing.assert_allclose(cams["frames"][f"{i:06d}"]["t"], truth.t[i])
    frame = cv2.imread(str(tmp_path / "m" / "frames" / "000001.png"), cv2.IMREAD_UNCHANGED)
    assert frame.shape == (H, W, 3) and frame.dtype == np.uint8
    c = truth.centres()
    assert np.linalg.norm(c[1] - c[0]) > 2.0  # two frames span the whole path

    truth = sr.make_room_scene(tmp_path / "s", n_frames=3, width=W, height=H, seed=SEED,
                               camera="static", with_masks=False, write_cameras="intrinsics",
                               camera_motion="unknown")
    assert yaml.safe_load((tmp_path / "s" / "scene.yaml").read_text())["camera_motion"] == "unknown"
    assert "frames" not in json.loads((tmp_path / "s" / "cameras.json").read_text())
    assert not (tmp_path / "s" / "humans").exists()
    assert all(np.array_equal(truth.R[i], truth.R[0]) and np.array_equal(truth.t[i], truth.t[0])
               for i in range(3))

    sr.make_room_scene(tmp_path / "e", n_frames=1, width=W, height=H, seed=SEED, with_person=False)
    assert not (tmp_path / "e" / "humans").exists() and not (tmp_path / "e" / "cameras.json").exists()
    with pytest.raises(FileExistsError):
        sr.make_room_scene(tmp_path / "e", n_frames=1, width=W, height=H, seed=SEED)
