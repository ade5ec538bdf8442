"""Synthetic places rendered by the fixture mesh renderer."""

import numpy as np

from glimpse.fixtures.mesh_render import render_meshes
from glimpse.fixtures.places import background_sphere, pillar, room, table

K = np.array([[60.0, 0, 39.5], [0, 60.0, 29.5], [0, 0, 1]])
R_DOWN = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, 1.0]])  # camera y down = world -y: level, facing +z


def camera_at(centre):
    return R_DOWN, -R_DOWN @ np.asarray(centre, float)


def test_a_room_surrounds_the_camera_with_texture():
    R, t = camera_at([0.0, 1.6, -2.0])
    view = render_meshes(room(0), K, R, t, 80, 60, supersample=2)
    assert (view.owner >= 0).all()  # every pixel sees a surface
    assert view.depth.min() > 0.3 and view.depth.max() < 13.0
    assert view.rgb.std() > 0.08  # textured, not flat
    again = render_meshes(room(0), K, R, t, 80, 60, supersample=2)
    assert np.array_equal(view.rgb, again.rgb)  # deterministic


def test_a_table_hides_what_is_behind_it_below_its_top():
    R, t = camera_at([0.0, 1.0, -2.0])
    meshes = room(1) + table(2, (0.0, 0.5))
    view = render_meshes(meshes, K, R, t, 80, 60, supersample=1)
    table_ids = set(range(6, len(meshes)))
    v, u = 45, 40  # below the horizon, straight ahead: the table's front face
    assert view.owner[v, u] in table_ids and view.depth[v, u] < 2.2
    assert view.owner[5, 40] not in table_ids  # above the table top: the wall behind


def test_the_background_sphere_and_a_pillar():
    R, t = camera_at([0.0, 1.6, 0.0])
    sphere = background_sphere(3, np.array([0.0, 1.0, 0.0]), 30.0)
    view = render_meshes([sphere, pillar(4, (0.0, 3.0))], K, R, t, 80, 60, supersample=1)
    assert (view.owner >= 0).all() and view.owner[30, 40] == 1
    assert abs(view.depth[30, 40] - (3.0 - 0.25)) < 0.05
    assert 25.0 < view.depth[30, 5] < 32.0
