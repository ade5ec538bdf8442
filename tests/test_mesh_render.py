"""The fixture mesh renderer: OpenCV pixel convention, exact depth and ownership, anti-aliasing."""

import numpy as np
import pytest

from glimpse.fixtures.mesh_render import AMBIENT, DIFFUSE, Mesh, render_meshes

W, H = 40, 30
K = np.array([[35.0, 0, 19.5], [0, 35.0, 14.5], [0, 0, 1]])


def quad(centre, half_size, normal_axis=2, colour=(1.0, 1.0, 1.0)) -> Mesh:
    """An axis-aligned square in the plane normal to ``normal_axis``."""
    a, b = [i for i in range(3) if i != normal_axis]
    corners = np.tile(np.asarray(centre, float), (4, 1))
    for k, (sa, sb) in enumerate(((-1, -1), (1, -1), (1, 1), (-1, 1))):
        corners[k, a] += sa * half_size
        corners[k, b] += sb * half_size
    return Mesh(corners, np.array([[0, 1, 2], [0, 2, 3]]), np.tile(colour, (4, 1)),
                uvs=np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float))


def pose(yaw: float, t) -> tuple[np.ndarray, np.ndarray]:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]), np.asarray(t, float)


def test_a_point_lands_on_the_pixel_opencv_puts_it():
    R, t = pose(0.3, [0.1, -0.2, 0.5])
    for u, v in ((3, 4), (31, 22), (19, 14)):
        z = 2.0
        cam = z * np.linalg.solve(K, [u, v, 1.0])
        world = R.T @ (cam - t)
        # a tiny square facing the camera, about 0.6 px wide: it covers one pixel centre only
        half = 0.3 * z / K[0, 0]
        square = quad(np.zeros(3), half)
        square.vertices = (square.vertices @ R) + world  # rotate with the camera so it faces it
        view = render_meshes([square], K, R, t, W, H, supersample=1)
        assert list(zip(*np.nonzero(view.owner >= 0))) == [(v, u)]
        assert view.depth[v, u] == pytest.approx(z, rel=1e-5)


def test_depth_is_the_camera_z_of_the_surface_at_each_pixel_centre():
    R, t = pose(0.0, [0.0, 0.0, 0.0])
    plane = quad([0.0, 0.0, 3.0], 10.0)
    plane.vertices[:, 2] += 0.4 * plane.vertices[:, 0]  # tilted: z = 3 + 0.4 x
    view = render_meshes([plane], K, R, t, W, H, supersample=1)
    v, u = np.mgrid[0:H, 0:W]
    ray_x = (u - K[0, 2]) / K[0, 0]
    expected = 3.0 / (1 - 0.4 * ray_x)  # z of the ray (x = z ray_x) on the plane
    np.testing.assert_allclose(view.depth, expected, rtol=1e-5)


def test_the_nearer_mesh_owns_the_overlap_and_colours_blend_at_edges():
    R, t = pose(0.0, [0.0, 0.0, 0.0])
    far = quad([0.0, 0.0, 4.0], 0.5, colour=(1.0, 0.0, 0.0))
    near = quad([0.3, 0.0, 2.0], 0.2, colour=(0.0, 1.0, 0.0))
    view = render_meshes([far, near], K, R, t, W, H, supersample=4)
    centre_u = int(round(K[0, 0] * 0.3 / 2.0 + K[0, 2]))
    # the far square spans u in [15.125, 23.875], the near one [21.25, 28.25]
    assert view.owner[14, centre_u] == 1 and view.owner[14, 17] == 0 and view.owner[0, 0] == -1
    lit = AMBIENT + DIFFUSE  # faces the camera
    np.testing.assert_allclose(view.rgb[14, centre_u], [0.0, lit, 0.0], atol=1 / 255)
    np.testing.assert_allclose(view.rgb[14, 17], [lit, 0.0, 0.0], atol=1 / 255)
    # pixel 15's four sub-samples sit at u = 14.625, 14.875, 15.125, 15.375: two are covered
    assert view.rgb[14, 15, 0] == pytest.approx(lit / 2, abs=2 / 255)
    assert view.owner[14, 15] == -1  # its centre (15.0) is not


def test_textures_are_sampled_with_opengl_uv_origin():
    R, t = pose(0.0, [0.0, 0.0, 0.0])
    square = quad([0.0, 0.0, 1.0], 0.5)
    texture = np.zeros((64, 64, 3), np.uint8)
    texture[:32, :, 0] = 255  # first rows = bottom of the texture (v near 0): red
    texture[32:, :, 2] = 255  # top half: blue
    square.texture = texture
    view = render_meshes([square], K, R, t, W, H, supersample=2)
    # y down in the image: the top rows see world y < 0, i.e. the quad's corners with uv v = 0 (red)
    assert view.rgb[5, 20, 0] > 0.5 and view.rgb[5, 20, 2] < 0.1
    assert view.rgb[25, 20, 2] > 0.5 and view.rgb[25, 20, 0] < 0.1


def test_empty_sub_samples_take_the_background_colour():
    R, t = pose(0.0, [0.0, 0.0, 0.0])
    far = quad([0.0, 0.0, 4.0], 0.5, colour=(1.0, 0.0, 0.0))
    background = (0.2, 0.4, 0.6)
    view = render_meshes([far], K, R, t, W, H, supersample=4, background=background)
    np.testing.assert_allclose(view.rgb[0, 0], background, atol=1e-6)  # no surface at all
    lit = AMBIENT + DIFFUSE
    np.testing.assert_allclose(view.rgb[14, 17], [lit, 0.0, 0.0], atol=1 / 255)  # wholly covered
    # pixel 15's sub-samples: two of four columns covered (as in the test above), so half the background
    half = (np.array([lit, 0.0, 0.0]) + np.array(background)) / 2
    np.testing.assert_allclose(view.rgb[14, 15], half, atol=2 / 255)
