"""MP4 writing (glimpse.io.video) and the overlay's drawing order (glimpse.fit.overlay)."""

import numpy as np
import pytest

from glimpse.cameras.model import PinholeCamera
from glimpse.fit.overlay import OverlayBody, overlay_frame
from glimpse.io.video import read_mp4, write_mp4


def test_mp4_round_trip_keeps_frames_and_pads_odd_sizes(tmp_path):
    rng = np.random.default_rng(0)
    frames = []
    for k in range(5):
        frame = np.full((33, 47, 3), 40 * k, np.uint8)
        frame[5:20, 10:30] = rng.integers(0, 255, 3)
        frames.append(frame)
    assert write_mp4(tmp_path / "v.mp4", iter(frames), fps=10) == 5
    video = read_mp4(tmp_path / "v.mp4")
    assert video.shape == (5, 34, 48, 3)
    for k in range(5):
        assert np.abs(video[k, :33, :47].astype(int) - frames[k]).mean() < 4
    assert not list(tmp_path.glob("*.partial*"))


def test_mp4_refuses_frames_of_changing_size_and_leaves_no_file(tmp_path):
    frames = [np.zeros((8, 8, 3), np.uint8), np.zeros((10, 8, 3), np.uint8)]
    with pytest.raises(ValueError, match="frame 1"):
        write_mp4(tmp_path / "v.mp4", frames, fps=5)
    assert not (tmp_path / "v.mp4").exists()


def _square(z: float, size: float) -> tuple[np.ndarray, np.ndarray]:
    """A dense grid of points on a square facing the camera at depth z, and a triangle list."""
    u, v = np.meshgrid(np.linspace(-size, size, 60), np.linspace(-size, size, 60))
    points = np.stack([u.ravel(), v.ravel(), np.full(u.size, z)], 1)
    index = np.arange(3600).reshape(60, 60)
    faces = np.concatenate([np.stack([index[:-1, :-1].ravel(), index[1:, :-1].ravel(), index[:-1, 1:].ravel()], 1),
                            np.stack([index[1:, :-1].ravel(), index[1:, 1:].ravel(), index[:-1, 1:].ravel()], 1)])
    return points, faces


def test_the_nearer_body_covers_the_farther_one():
    camera = PinholeCamera(K=np.array([[50.0, 0, 32], [0, 50.0, 32], [0, 0, 1]]), R=np.eye(3), t=np.zeros(3),
                           width=64, height=64)
    far, faces = _square(4.0, 1.0)
    near, _ = _square(2.0, 0.2)
    image = np.zeros((64, 64, 3), np.uint8)
    drawn = overlay_frame(image, camera, faces, [OverlayBody(near, None, None, (0, 0, 255)),
                                                 OverlayBody(far, None, None, (255, 0, 0))])
    centre, edge = drawn[32, 32], drawn[32, 22]
    assert centre[2] > 100 and centre[0] == 0  # the near blue square, in front
    assert edge[0] > 100 and edge[2] == 0  # the far red square around it
    assert (drawn[0, 0] == 0).all()  # nothing drawn outside both
