"""The CPU z-buffer triangle rasterizer (glimpse.render.mesh_raster) against exact geometry and
against the fixtures' OpenGL renderer (an independent implementation)."""

import numpy as np
import pytest
import torch

from glimpse.body.model import BodyModel
from glimpse.fixtures.mesh_render import Mesh, render_meshes
from glimpse.fixtures.scenes import FREE_BODY, intrinsics, look_at_pose
from glimpse.render.composite_cpu import available
from glimpse.render.mesh_raster import rasterize_meshes, rasterize_triangles

K_SMALL = np.array([[10.0, 0.0, 4.0], [0.0, 10.0, 4.0], [0.0, 0.0, 1.0]])


def test_coverage_is_the_pixel_centres_inside_the_triangle():
    # a right triangle whose legs pass through pixel centres: (1,1), (6,1), (1,6) in pixels at z = 2
    corners_px = np.array([[1.0, 1.0], [6.0, 1.0], [1.0, 6.0]])
    points = np.concatenate([(corners_px - 4.0) / 10.0 * 2.0, np.full((3, 1), 2.0)], axis=1)
    raster = rasterize_triangles(points, np.array([[0, 1, 2]]), K_SMALL, 8, 8)
    v, u = np.mgrid[0:8, 0:8]
    expected = (u >= 1) & (v >= 1) & (u + v <= 7)
    assert np.array_equal(raster.face >= 0, expected)
    assert np.allclose(raster.depth[expected], 2.0) and np.isinf(raster.depth[~expected]).all()


def test_depth_is_perspective_correct_on_a_tilted_plane():
    # the plane z = 2 + 0.5 x (camera coordinates), a large triangle on it
    xy = np.array([[-1.0, -1.0], [1.5, -1.0], [-1.0, 1.5]])
    points = np.concatenate([xy, (2.0 + 0.5 * xy[:, 0])[:, None]], axis=1)
    raster = rasterize_triangles(points, np.array([[0, 2, 1]]), K_SMALL, 8, 8)  # either winding
    v, u = np.nonzero(raster.face >= 0)
    ray_x = (u - 4.0) / 10.0  # x / z along the pixel's ray
    assert len(u) > 20
    assert np.allclose(raster.depth[v, u], 2.0 / (1.0 - 0.5 * ray_x))


def test_nearest_body_and_depth_agree_with_the_opengl_renderer():
    model = BodyModel.from_file(FREE_BODY, dtype=torch.float64)
    g = torch.Generator().manual_seed(0)
    pose = 0.2 * torch.randn(1, 69, generator=g, dtype=torch.float64)
    near = model(torch.zeros(1, 10, dtype=torch.float64), torch.zeros(1, 3, dtype=torch.float64), pose,
                 torch.tensor([[0.0, 0.0, 3.0]], dtype=torch.float64)).vertices[0].numpy()
    far = near + [0.3, 0.0, 1.0]
    faces = model.faces.numpy()
    K = intrinsics(320, 240, 60.0)
    R, t = look_at_pose(np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.5, 3.0]))
    raster = rasterize_triangles(np.concatenate([near, far]) @ R.T + t, np.concatenate([faces, faces + len(near)]),
                                 K, 320, 240)
    owner = np.where(raster.face >= 0, raster.face // len(faces), -1)
    gl = render_meshes([Mesh(near, faces, np.ones((len(near), 3))), Mesh(far, faces, np.ones((len(far), 3)))],
                       K, R, t, 320, 240, supersample=1)
    covered = (gl.owner >= 0) | (owner >= 0)
    assert covered.sum() > 3000 and (owner == 1).sum() > 500  # both bodies show
    assert (owner != gl.owner).sum() <= 0.002 * covered.sum()
    same = (owner == gl.owner) & (owner >= 0)
    close = np.isclose(raster.depth[same], gl.depth[same], rtol=1e-3)
    assert close.mean() > 0.995  # (a few silhouette pixels of one body can show different layers of it)


@pytest.mark.skipif(not available(), reason="the C++ kernel does not build here")
def test_the_cpp_z_buffer_equals_the_numpy_reference_to_the_bit():
    """Random triangle soups (overlapping, both windings, slivers, edges through pixel centres, some off the
    image or behind the camera), and two posed bodies, one in front of the other: the same faces and depths."""
    rng = np.random.default_rng(7)
    K = np.array([[60.0, 0.0, 31.5], [0.0, 60.0, 23.5], [0.0, 0.0, 1.0]])
    for trial in range(6):
        count = 400
        centres = np.concatenate([rng.uniform(-1.2, 1.2, (count, 2)), rng.uniform(-0.5, 4.0, (count, 1))], 1)
        points = (centres[:, None, :] + rng.normal(0.0, 0.15 * (trial + 1), (count, 3, 3))).reshape(-1, 3)
        if trial % 2:  # corners on pixel centres and on a shared depth: edges through centres, exact depth ties
            pixels = np.round(points[:, :2] / points[:, 2:] * 60.0 + [31.5, 23.5]) - [31.5, 23.5]
            points[:, 2] = np.round(points[:, 2])
            points[:, :2] = pixels / 60.0 * points[:, 2:]
        faces = np.arange(len(points)).reshape(-1, 3)
        faces[::5] = faces[::5, ::-1]
        kernel = rasterize_triangles(points, faces, K, 64, 48, use_kernel=True)
        reference = rasterize_triangles(points, faces, K, 64, 48, use_kernel=False)
        assert (reference.face >= 0).sum() > 500
        assert np.array_equal(kernel.face, reference.face) and np.array_equal(kernel.depth, reference.depth)
    model = BodyModel.from_file(FREE_BODY, dtype=torch.float64)
    pose = 0.2 * torch.randn(1, 69, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    body = model(torch.zeros(1, 10, dtype=torch.float64), torch.zeros(1, 3, dtype=torch.float64), pose,
                 torch.tensor([[0.0, -0.3, 3.0]], dtype=torch.float64)).vertices[0].numpy()
    K = intrinsics(320, 240, 60.0)
    meshes = [body, body + [0.2, 0.0, 0.8]]
    faces = model.faces.numpy()
    assert all(np.array_equal(a, b) for a, b in zip(
        vars(rasterize_meshes(meshes, faces, K, 320, 240)).values(),
        vars(_numpy_meshes(meshes, faces, K, 320, 240)).values()))


@pytest.mark.skipif(not available(), reason="the C++ kernel does not build here")
def test_the_cpp_z_buffer_follows_numpy_on_broken_coordinates():
    """Coordinates that are not finite, or so large that products overflow or boxes leave any integer range: the
    kernel gives what numpy gives (nothing covered here), instead of walking or writing outside the image."""
    K = np.array([[60.0, 0.0, 31.5], [0.0, 60.0, 23.5], [0.0, 0.0, 1.0]])
    good = np.array([[-0.3, -0.3, 2.0], [0.3, -0.3, 2.0], [0.0, 0.3, 2.0]])
    cases = {"nan": [[np.nan, 0.0, 1.0], [0.1, 0.0, 1.0], [0.0, 0.1, 1.0]],
             "minus inf": [[-np.inf, 0.0, 1.0], [0.1, 0.0, 1.0], [0.0, 0.1, 1.0]],
             "inf": [[np.inf, 0.0, 1.0], [np.inf, 0.1, 1.0], [np.inf, 0.2, 1.0]],
             "beyond int64": [[1e18, 0.0, 1.0], [2e18, 0.0, 1.0], [1e18, 0.2, 1.0]],
             "overflowing": [[-1e200, -1e200, 1.0], [1e200, -1e200, 1.0], [0.0, 1e200, 1.0]]}
    for name, corners in cases.items():
        points = np.concatenate([np.array(corners, float), good])
        faces = np.array([[0, 1, 2], [3, 4, 5]])
        kernel = rasterize_triangles(points, faces, K, 64, 48, use_kernel=True)
        with np.errstate(all="ignore"):  # numpy's overflow and invalid-value warnings are expected here
            reference = rasterize_triangles(points, faces, K, 64, 48, use_kernel=False)
        assert np.array_equal(kernel.face, reference.face), name
        assert np.array_equal(kernel.depth, reference.depth), name
        assert set(np.unique(kernel.face)) == {-1, 1}, name  # the good triangle only


def _numpy_meshes(meshes, faces, K, width, height):
    return rasterize_triangles(np.concatenate(meshes), np.concatenate([faces + k * len(meshes[0])
                                                                       for k in range(len(meshes))]),
                               K, width, height, use_kernel=False)
