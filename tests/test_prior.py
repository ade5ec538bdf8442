"""The surface prior and what it stands on: the body's mirror map, harmonic completion (against the
closed-form interpolation on a path), vertex visibility (front/back, people hiding people, static
occluders), orbit cameras, the never-seen pixels of a view, holes in a canonical person, and each loss term
doing its job."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from scipy.sparse import coo_matrix

from glimpse.body.config import BodyConfig, resolve_model_path
from glimpse.body.model import BodyModel
from glimpse.body.models import BodyModels
from glimpse.body.params import BodyParams
from glimpse.body.symmetry import mirror_vertex_map
from glimpse.cameras.model import PinholeCamera
from glimpse.cameras.orbit import orbit_camera
from glimpse.config import config_from_mapping, load_pipeline_yaml
from glimpse.eval.coverage import CoverageConfig, canonical_hole_share
from glimpse.eval.never_seen import PosedBodies, flat_bodies
from glimpse.eval.views import ScoredView
from glimpse.humans.person import initial_person
from glimpse.body.normals import vertex_normals
from glimpse.humans.visibility import BodyVisibility, VisibilityConfig, body_visibility
from glimpse.prior import PriorContext, make_prior
from glimpse.prior.complete import body_graph, part_groups, part_means, part_parents, screened_fill
from glimpse.prior.config import SurfacePriorConfig
from glimpse.render.config import RenderConfig
from glimpse.render.sh import rgb_to_sh_dc

PIPELINE = load_pipeline_yaml()
BODY = config_from_mapping(BodyConfig, PIPELINE["body"], "body")
SURFACE = config_from_mapping(SurfacePriorConfig, PIPELINE["prior_surface"], "prior_surface")
VISIBILITY = VisibilityConfig(depth_tolerance_m=0.03, max_view_angle_deg=80.0)
RENDER = RenderConfig(backend="auto", sh_degree=1, antialiased=False)
SIZE = 96


@pytest.fixture(scope="module")
def body_model() -> BodyModel:
    return BodyModel.from_file(resolve_model_path(BODY))


def _standing(frames: int = 1, transl=(0.0, 0.0, 0.0)) -> BodyParams:
    """A mean-shape body in the rest pose facing +z (the orbit's azimuth 0), pelvis at ``transl``."""
    return BodyParams(np.arange(frames), np.zeros(10), np.zeros((frames, 3)), np.zeros((frames, 69)),
                      np.tile(np.asarray(transl, float), (frames, 1)), 1.0, "free", np.zeros(frames, bool))


def _camera(azimuth_deg: float, centre=(0.0, 0.0, 0.0)) -> PinholeCamera:
    return orbit_camera(np.asarray(centre), azimuth_deg, 0.0, 3.0, 60.0, SIZE)


# --- the body's mirror and the completion ------------------------------------------------------------

def test_the_mirror_map_is_an_involution_onto_reflected_vertices(body_model):
    template = body_model.v_template.double().numpy()
    mirror, distance = mirror_vertex_map(template)
    assert np.array_equal(mirror[mirror], np.arange(len(template)))
    assert distance.max() < 0.005  # metres: the template is symmetric to a few millimetres
    left = template[:, 0] > 0.05
    assert (template[mirror[left], 0] < -0.04).all()


def held(known: np.ndarray) -> np.ndarray:
    """Confidences that hold the known vertices exactly (screened_fill's hard constraints)."""
    return np.where(known, np.inf, 0.0)


def test_the_fill_interpolates_linearly_along_a_path():
    """On a path graph the harmonic extension between two known ends is the straight line between them."""
    count = 11
    edges = np.stack([np.arange(count - 1), np.arange(1, count)], 1)
    graph = body_graph(edges, np.arange(count), 1.0, count)  # every vertex its own mirror: no mirror edges
    values = np.zeros((count, 2))
    values[0], values[-1] = [1.0, 0.0], [3.0, 10.0]
    known = np.zeros(count, bool)
    known[[0, -1]] = True
    filled = screened_fill(values, held(known), graph)
    line = np.linspace(0, 1, count)[:, None] * (values[-1] - values[0]) + values[0]
    np.testing.assert_allclose(filled, line, atol=1e-5)


def test_a_strong_mirror_edge_carries_a_seen_colour_across():
    """Vertex 1 (unknown) hangs between 0 (red, its mesh neighbour) and its mirror 2 (blue)."""
    edges = np.array([[0, 1]])
    mirror = np.array([0, 2, 1])
    values = np.array([[1.0, 0, 0], [0, 0, 0], [0, 0, 1.0]])
    known = np.array([True, False, True])
    filled = screened_fill(values, held(known), body_graph(edges, mirror, 9.0, 3))
    np.testing.assert_allclose(filled[1], [0.1, 0.0, 0.9], atol=1e-5)


def test_far_from_anything_seen_a_vertex_settles_on_its_parts_seen_colour():
    count = 30
    edges = np.stack([np.arange(count - 1), np.arange(1, count)], 1)
    graph = body_graph(edges, np.arange(count), 1.0, count)
    values = np.zeros((count, 1))
    values[[0, 1], 0] = 1.0, 3.0
    known = np.zeros(count, bool)
    known[[0, 1]] = True
    groups = part_groups(np.r_[0, 1, np.ones(count - 2, int)], np.arange(count))
    anchors = part_means(values, known, groups)  # part 1's seen mean is vertex 1's 3.0
    assert anchors[0, 0] == 1.0 and (anchors[1:, 0] == 3.0).all()
    filled = screened_fill(values, held(known), graph, anchors, anchor_weight=0.5)
    assert abs(filled[-1, 0] - 3.0) < 1e-3 and filled[1, 0] == 3.0
    mirrored = part_groups(np.array([0, 1, 2, 3]), np.array([1, 0, 3, 2]))
    assert mirrored.tolist() == [0, 0, 2, 2]  # a part and its mirror form one group


def test_a_faint_vertex_yields_to_its_neighbours_and_a_firm_one_keeps_its_colour():
    """Path 0-1-2: the ends held at 0 and 2, the middle's data 10 with confidence c. The energy
    (x - 0)^2 + (x - 2)^2 + c (x - 10)^2 is least at x = (2 + 10 c) / (2 + c)."""
    graph = body_graph(np.array([[0, 1], [1, 2]]), np.arange(3), 1.0, 3)
    values = np.array([[0.0], [10.0], [2.0]])
    for confidence in (0.01, 1.0, 1000.0):
        filled = screened_fill(values, np.array([np.inf, confidence, np.inf]), graph)
        assert filled[1, 0] == pytest.approx((2 + 10 * confidence) / (2 + confidence), rel=1e-9)
    assert filled[[0, 2], 0].tolist() == [0.0, 2.0]


def test_part_means_weigh_each_vertex_by_its_weight():
    values = np.array([[0.0], [4.0], [9.0]])
    known = np.array([True, True, False])
    groups = np.zeros(3, int)
    assert part_means(values, known, groups)[2, 0] == 2.0
    assert part_means(values, known, groups, weights=np.array([1.0, 3.0, 100.0]))[2, 0] == 3.0


def test_a_part_never_seen_takes_its_nearest_seen_ancestors_colour():
    # joints: 0 root (torso) -> 1 thigh -> 2 shin -> 3 foot; joint 4 labels no vertex, its child 5 hangs on it
    joint_parents = np.array([-1, 0, 1, 2, 0, 4])
    labels = np.array([0, 0, 1, 1, 2, 2, 3, 5])
    groups = part_groups(labels, np.arange(len(labels)))
    parents = part_parents(labels, groups, joint_parents)
    assert parents[[0, 1, 2, 3, 5]].tolist() == [-1, 0, 1, 2, 0]  # joint 5 skips the vertex-less joint 4
    values = np.array([[1.0], [1.0], [4.0], [6.0], [0.0], [0.0], [0.0], [0.0]])
    known = np.array([True, True, True, True, False, False, False, False])
    anchors = part_means(values, known, groups, parents)
    assert anchors[:, 0].tolist() == [1.0, 1.0, 5.0, 5.0, 5.0, 5.0, 5.0, 1.0]  # shin and foot: the thigh's
    assert part_means(values, known, groups)[4:, 0].tolist() == [3.0] * 4  # without parents: the overall mean
    known[4] = True  # one shin vertex of two is too few at a share of 0.6: the shin still takes the thigh's
    assert part_means(values, known, groups, parents, min_share=0.6)[4:6, 0].tolist() == [5.0, 5.0]
    assert part_means(values, known, groups, parents, min_share=0.5)[4:6, 0].tolist() == [0.0, 0.0]


def test_an_island_without_known_vertices_takes_the_known_mean():
    graph = coo_matrix((np.ones(2), ([2, 3], [3, 2])), shape=(4, 4)).tocsr()  # 0, 1 isolated and known
    values = np.array([[0.0], [1.0], [7.0], [7.0]])
    filled = screened_fill(values, held(np.array([True, True, False, False])), graph)
    np.testing.assert_allclose(filled[2:], 0.5, atol=1e-4)


# --- visibility ------------------------------------------------------------------------------------------

def test_vertex_normals_point_out_of_the_body(body_model):
    template = body_model.v_template.double().numpy()
    normals = vertex_normals(template, body_model.faces.numpy())
    chest = np.argmax(template[:, 2])  # the most forward vertex
    assert normals[chest, 2] > 0.8
    # the same sums, in the same order, as adding the faces' normals corner by corner; an unused vertex gets zero
    points = np.concatenate([template, [[9.0, 9.0, 9.0]]])
    faces = body_model.faces.numpy()
    corners = points[faces]
    face_normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    summed = np.zeros_like(points)
    for k in range(3):
        np.add.at(summed, faces[:, k], face_normals)
    expected = summed / np.maximum(np.linalg.norm(summed, axis=1, keepdims=True), 1e-300)
    assert np.array_equal(vertex_normals(points, faces), expected) and not vertex_normals(points, faces)[-1].any()


def test_a_camera_sees_the_front_not_the_back_and_people_and_occluders_hide(body_model):
    body = _standing()
    template = body_model(body.betas, body.global_orient, body.body_pose).vertices[0].double().numpy()
    facing = vertex_normals(template, body_model.faces.numpy())[:, 2]  # towards the camera at azimuth 0
    torso = (np.abs(template[:, 0]) < 0.12) & (template[:, 1] > 0.0) & (template[:, 1] < 0.4)  # no arm in front
    front = body_visibility(BodyModels(body_model), {"p0": body}, {0: _camera(0.0)}, SIZE, SIZE, {}, VISIBILITY)["p0"]
    assert 0.25 < front.seen.mean() < 0.6
    assert front.seen[torso & (facing > 0.5)].mean() > 0.95 and not front.seen[facing < -0.2].any()
    back = body_visibility(BodyModels(body_model), {"p0": body}, {0: _camera(180.0)}, SIZE, SIZE, {}, VISIBILITY)["p0"]
    assert (front.seen & back.seen).mean() < 0.05  # only the sides, within the tolerances
    assert front.best_px_per_m[front.seen].min() > 0 and (front.best_cosine[~front.seen] == 0).all()
    blocker = _standing(transl=(0.0, 0.0, 1.0))  # a person between the camera and p0
    hidden = body_visibility(BodyModels(body_model), {"p0": body, "p1": blocker}, {0: _camera(0.0)}, SIZE, SIZE, {},
                             VISIBILITY)
    assert hidden["p0"].seen.mean() < 0.25 * front.seen.mean() and hidden["p1"].seen.mean() > 0.25
    walled = body_visibility(BodyModels(body_model), {"p0": body}, {0: _camera(0.0)}, SIZE, SIZE,
                             {0: {"p0": np.zeros((SIZE, SIZE), bool)}}, VISIBILITY)["p0"]
    assert not walled.seen.any()  # a mask without the person: a table (or anything) hides it
    upper = np.zeros((SIZE, SIZE), bool)
    upper[: SIZE // 2] = True  # image rows above the middle: the person is visible only there
    half = body_visibility(BodyModels(body_model), {"p0": body}, {0: _camera(0.0)}, SIZE, SIZE, {0: {"p0": upper}},
                           VISIBILITY)["p0"]
    assert (half.seen <= front.seen).all() and 0.3 < half.seen.sum() / front.seen.sum() < 0.7
    assert not half.seen[template[:, 1] < template[:, 1].min() + 0.5].any()  # the legs were behind it


def test_visibility_files_round_trip(tmp_path):
    record = BodyVisibility(np.array([0, 3]), np.array([0.0, 0.9]), np.array([0.0, 120.0]))
    record.write(tmp_path / "visibility.npz")
    again = BodyVisibility.read(tmp_path / "visibility.npz")
    assert np.array_equal(again.seen, [False, True]) and again.best_px_per_m[1] == 120.0


def test_orbit_cameras_look_at_the_centre_with_the_body_up_and_its_left_on_the_right():
    centre = np.array([0.1, 0.9, -0.2])
    for azimuth, elevation in ((0.0, 0.0), (90.0, 20.0), (-150.0, -25.0)):
        camera = orbit_camera(centre, azimuth, elevation, 2.2, 49.1, 128)
        assert np.linalg.norm(-camera.R.T @ camera.t - centre) == pytest.approx(2.2)
        uv = camera.project(centre[None])[0][0]
        np.testing.assert_allclose(uv, [63.5, 63.5], atol=1e-6)
        above = camera.project((centre + [0.0, 0.3, 0.0])[None])[0][0]
        assert above[1] < 63.5  # up is up in the image
    front = orbit_camera(centre, 0.0, 0.0, 2.2, 49.1, 128)
    assert front.project((centre + [0.3, 0.0, 0.0])[None])[0][0, 0] > 63.5  # facing the body: its left on our right


# --- never-seen pixels -------------------------------------------------------------------------------------

def test_never_seen_pixels_cover_the_back_seen_from_behind_and_nothing_from_the_front(body_model):
    body = _standing()
    visibility = body_visibility(BodyModels(body_model), {"p0": body}, {0: _camera(0.0)}, SIZE, SIZE, {}, VISIBILITY)
    person = initial_person("p0", body_model, body, 30.0, BODY.skinning, 0.5, 0.9, 3, 0)
    bodies = PosedBodies([person], visibility, BodyModels(body_model))

    def view(azimuth: float) -> ScoredView:
        return ScoredView("v", 0, _camera(azimuth), None, None, {})

    from_front, from_behind = bodies.in_view(view(0.0)), bodies.in_view(view(180.0))
    assert (from_front.owner == 0).sum() > 300 and (from_behind.owner == 0).sum() > 300
    assert from_front.never_seen.sum() < 0.02 * (from_front.owner == 0).sum()
    assert from_behind.never_seen.sum() > 0.9 * (from_behind.owner == 0).sum()
    flat = flat_bodies(from_behind, [np.array([0.2, 0.4, 0.6])])
    assert np.allclose(flat[from_behind.owner == 0], [0.2, 0.4, 0.6]) and (flat[from_behind.owner < 0] == 0).all()


# --- holes in the canonical person -------------------------------------------------------------------------

def test_a_person_covering_their_body_has_no_holes_and_a_faded_half_shows_as_holes(body_model):
    person = initial_person("p0", body_model, _standing(), 30.0, BODY.skinning, 0.5, 0.9, 3, 0)
    config = CoverageConfig(views=4, size_px=96)
    faces = body_model.faces.numpy()
    covered = canonical_hole_share(person, faces, config, RENDER, torch.device("cpu"))
    with torch.no_grad():
        person.model.opacity_logits[person.model.means[:, 0] > 0.0] = -10.0  # the body's left half fades away
    faded = canonical_hole_share(person, faces, config, RENDER, torch.device("cpu"))
    assert covered < 0.02
    # about half of the front and back views; from the sides the other half shows through (but not the arm)
    assert 0.15 < faded < 0.35


# --- the surface prior -------------------------------------------------------------------------------------

def _prior_and_person(body_model, config: SurfacePriorConfig = SURFACE, views: int = 4):
    body = _standing()
    person = initial_person("p0", body_model, body, 30.0, BODY.skinning, 0.5, 0.9, 3, 1)
    visibility = body_visibility(BodyModels(body_model), {"p0": body}, {0: _camera(0.0)}, SIZE, SIZE, {}, VISIBILITY)
    config = replace(config, start_at=1, refresh_every=1000, views_per_person=views)
    prior = make_prior("surface", PriorContext([person], visibility, BodyModels(body_model), RENDER, 0, lambda i: i),
                       config)
    return prior, person, visibility["p0"].seen


def test_unseen_gaussians_are_pulled_to_the_colour_seen_on_the_body_and_seen_ones_are_left_alone(body_model):
    prior, person, seen = _prior_and_person(body_model, replace(SURFACE, grazing_colour=False))
    red = torch.tensor([0.9, 0.1, 0.1])
    with torch.no_grad():  # the camera saw a red front; the back stays grey
        person.model.sh_dc[torch.as_tensor(seen), 0] = rgb_to_sh_dc(red)
    terms = prior.losses(1, [person])
    assert set(terms) == {"loss_prior_colour", "loss_prior_seen_colour", "loss_prior_surface", "loss_prior_needle",
                          "loss_prior_silhouette"}
    terms["loss_prior_colour"].backward()
    grad = person.model.sh_dc.grad[:, 0].norm(dim=1)
    assert grad[torch.as_tensor(seen)].abs().max() == 0 and (grad[torch.as_tensor(~seen)] > 0).float().mean() > 0.9
    completed = prior.people["p0"].vertex_colours  # the whole back is completed red, not left grey
    assert torch.allclose(completed[torch.as_tensor(~seen)].mean(0), red, atol=0.05)


def test_surfaces_seen_only_edge_on_are_pulled_to_the_completed_colour_too(body_model):
    prior, person, _ = _prior_and_person(body_model, replace(SURFACE, grazing_colour=True))
    vertex = prior._nearest(person)
    state = prior.people["p0"]
    with torch.no_grad():  # the head-on surface was seen red; the edge-on one kept a grey from the silhouette
        person.model.sh_dc[state.colour_source[vertex], 0] = rgb_to_sh_dc(torch.tensor([0.9, 0.1, 0.1]))
    prior.losses(1, [person])["loss_prior_colour"].backward()
    grad = person.model.sh_dc.grad[:, 0].norm(dim=1)
    edge_on = state.seen[vertex] & ~state.colour_source[vertex]
    assert edge_on.sum() > 50 and (grad[edge_on] > 0).float().mean() > 0.9
    assert grad[state.colour_source[vertex]].abs().max() == 0  # what lends the colour is left alone


def test_seen_colour_evens_out_speckles_among_what_was_seen(body_model):
    """A red front with a few green Gaussians (background caught by a person seen small): the completed colour
    of a speckle's vertex leans to its red neighbours, and seen_colour pulls the speckle that way; at 0 there is no
    such term."""
    off, off_person, _ = _prior_and_person(body_model, replace(SURFACE, seen_colour=0.0))
    assert "loss_prior_seen_colour" not in off.losses(1, [off_person])
    prior, person, _ = _prior_and_person(body_model)
    state, vertex = prior.people["p0"], prior._nearest(person)
    source = torch.nonzero(state.colour_source[vertex]).squeeze(1)
    speckles = source[::7]
    with torch.no_grad():
        person.model.sh_dc[source, 0] = rgb_to_sh_dc(torch.tensor([0.9, 0.1, 0.1]))
        person.model.sh_dc[speckles, 0] = rgb_to_sh_dc(torch.tensor([0.1, 0.9, 0.1]))
    prior.losses(1, [person])["loss_prior_seen_colour"].backward()
    step = -person.model.sh_dc.grad[speckles, 0]  # the descent direction, in SH DC (a positive multiple of RGB)
    assert len(speckles) > 100 and (step[:, 0] > 0).float().mean() > 0.95 and (step[:, 1] < 0).float().mean() > 0.95


def test_the_prior_pulls_stray_unseen_gaussians_back_and_flattens_needles(body_model):
    prior, person, seen = _prior_and_person(body_model)
    unseen_rows = torch.nonzero(torch.as_tensor(~seen)).squeeze(1)[:50]
    with torch.no_grad():
        person.model.means[unseen_rows] += torch.tensor([0.0, 0.0, -0.2])  # 20 cm behind the back
        person.model.log_scales[:20] = torch.log(torch.tensor([0.04, 0.002, 0.002]))  # needles
    optimizer = torch.optim.Adam(person.model.parameters(), lr=2e-2)
    before = prior.losses(1, [person])
    for step in range(1, 31):
        terms = prior.losses(step, [person])
        (terms["loss_prior_surface"] + terms["loss_prior_needle"]).backward()
        optimizer.step()
        optimizer.zero_grad()
    after = prior.losses(31, [person])
    assert after["loss_prior_surface"] < 0.3 * before["loss_prior_surface"]
    assert after["loss_prior_needle"] < 0.5 * before["loss_prior_needle"]


def test_the_silhouette_term_fills_holes_and_trims_spikes(body_model):
    config = replace(SURFACE, silhouette_fill=1.0, silhouette_trim=1.0)
    prior, person, _ = _prior_and_person(body_model, config, views=1)
    with torch.no_grad():
        person.model.opacity_logits[::2] = -6.0  # half the body transparent
        person.model.means[:30] *= 1.5  # spikes outside the body
    view = prior.people["p0"].views[0]
    assert view.inside.sum() > 100 and view.outside.sum() > 100
    optimizer = torch.optim.Adam([person.model.opacity_logits], lr=0.2)
    first = None
    for step in range(1, 61):
        loss = prior.losses(step, [person])["loss_prior_silhouette"]
        first = float(loss.detach()) if first is None else first
        loss.backward()
        optimizer.step()
        optimizer.zero_grad()
    assert float(prior.losses(61, [person])["loss_prior_silhouette"].detach()) < 0.5 * first
    assert person.model.opacities()[:30].mean() < 0.5


def test_no_term_before_start_at_and_the_state_round_trips(body_model):
    _, person, _ = _prior_and_person(body_model)
    late = make_prior("surface", PriorContext([person], {"p0": BodyVisibility.empty(body_model.num_vertices)},
                                              BodyModels(body_model), RENDER, 0, lambda i: i),
                      replace(SURFACE, start_at=5, views_per_person=1))
    assert late.losses(4, [person]) == {} and late.losses(5, [person])
    state = late.state_dict()
    other = make_prior("surface", PriorContext([person], {"p0": BodyVisibility.empty(body_model.num_vertices)},
                                               BodyModels(body_model), RENDER, 0, lambda i: i),
                       replace(SURFACE, start_at=5, views_per_person=1))
    other.load_state_dict(state)
    assert torch.equal(other.people["p0"].vertex_colours, late.people["p0"].vertex_colours)
    assert other.people["p0"].coloured_at == 5 and math.isfinite(float(other.losses(6, [person])["loss_prior_needle"].detach()))
