"""Synthetic clothed people: determinism, regions, clothing geometry, posing, front/back textures."""

from dataclasses import replace

import numpy as np
import pytest

from glimpse.body.model import BodyModel
from glimpse.body.motion import builtin_motion
from glimpse.fixtures.mesh_render import Mesh, render_meshes
from glimpse.fixtures.people import REGIONS, dress, person_mesh, pose_person, random_look

MODEL_PATH = "glimpse/body/assets/free_body.npz"
TEXTURE = 256
W, H, FOCAL = 120, 180, 200.0
FRONT_BACK_MIN_DIFF = 0.08  # mean |front - mirrored back| colour over shirt pixels, striped look
MIRROR_MAX_DIFF = 0.04  # mean |view - mirrored view| over shirt pixels of a plain look, mirrored cameras
MARK_MIN_PIXELS = 20  # pixels the back mark changes (by > MARK_PIXEL_DIFF) when seen from behind
MARK_PIXEL_DIFF = 0.2
SHIRT = REGIONS.index("shirt")


@pytest.fixture(scope="module")
def model() -> BodyModel:
    return BodyModel.from_file(MODEL_PATH)


@pytest.fixture(scope="module")
def striped(model):
    return dress(model, replace(random_look(3, "neutral"), shirt_pattern="stripes"), TEXTURE)


def rest_joints(model, person) -> np.ndarray:
    from glimpse.fixtures.people import _rest_body, look_betas
    return _rest_body(model, look_betas(model, person.look))[1]


def camera(yaw: float, distance: float = 3.0, height: float = -0.2):
    """K, R, t of a camera on a circle around the y axis looking at it; yaw 0: in front (+z)."""
    K = np.array([[FOCAL, 0, (W - 1) / 2], [0, FOCAL, (H - 1) / 2], [0, 0, 1]])
    forward = -np.array([np.sin(yaw), 0.0, np.cos(yaw)])  # towards the axis
    down = np.array([0.0, -1.0, 0.0])
    right = np.cross(down, forward)
    R = np.stack([right, down, forward])
    centre = np.array([0.0, height, 0.0]) - distance * forward
    return K, R, -R @ centre


def shirt_mask(person, posed, K, R, t) -> np.ndarray:
    """Pixels (H, W) whose surface is shirt: a render with the shirt white and the rest black."""
    colours = np.zeros((len(posed), 3))
    colours[person.region == SHIRT] = 1.0
    view = render_meshes([Mesh(posed, person.faces, colours)], K, R, t, W, H, supersample=1)
    return view.rgb[..., 0] > 0.3


def test_same_seed_same_person(model):
    a, b = (dress(model, random_look(7), TEXTURE) for _ in range(2))
    for name in ("rest_vertices", "faces", "weights", "uvs", "texture", "region", "body_index"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    c = dress(model, random_look(8), TEXTURE)
    assert not np.array_equal(a.texture, c.texture)


@pytest.mark.parametrize("preset", ["neutral", "child", "heavy"])
def test_regions_follow_the_body(model, preset):
    person = dress(model, random_look(5, preset), TEXTURE)
    joints = rest_joints(model, person)
    y = person.rest_vertices[:, 1]
    counts = np.bincount(person.region, minlength=len(REGIONS))
    assert (counts > 0).all(), dict(zip(REGIONS, counts))
    ankle_y = joints[7, 1]
    assert y[person.region == REGIONS.index("shoes")].max() < ankle_y + 0.06
    ear_height = rest_ear_height(model, person)
    assert y[person.region == REGIONS.index("hair")].min() > ear_height - 0.06
    shirt_y = y[person.region == SHIRT]
    assert shirt_y.min() > joints[1, 1] - 0.05 and shirt_y.max() < joints[15, 1]  # hips .. head
    hands = np.isin(person.weights.argmax(1), (20, 21, 22, 23))
    assert (person.region[hands] == REGIONS.index("skin")).all()
    assert (person.faces < len(person.rest_vertices)).all() and person.uvs.min() >= 0 and person.uvs.max() <= 1


def rest_ear_height(model, person) -> float:
    from glimpse.fixtures.people import _landmark, _rest_body, look_betas
    vertices = _rest_body(model, look_betas(model, person.look))[0]
    return float(_landmark(model, vertices, "left_ear")[1])


def test_clothes_stand_off_the_body(model, striped):
    from glimpse.body.normals import vertex_normals
    from glimpse.fixtures.people import _rest_body, look_betas
    bare = _rest_body(model, look_betas(model, striped.look))[0]
    normals = vertex_normals(bare, np.asarray(model.data.faces))
    moved = striped.rest_vertices - bare[striped.body_index]
    outward = (moved * normals[striped.body_index]).sum(1)
    shirt = striped.region == SHIRT
    assert 0.005 < outward[shirt].mean() < 0.06
    assert np.linalg.norm(moved, axis=1).max() < 0.10
    for region in ("trousers", "hair"):
        assert outward[striped.region == REGIONS.index(region)].mean() > 0.005


def test_posing_matches_the_body(model):
    look = replace(random_look(9, "woman"), loose_shirt_m=0.0, loose_trousers_m=0.0, hair_volume_m=0.0)
    bare = dress(model, look, TEXTURE)
    from glimpse.fixtures.people import SHOE_OFFSET_M, look_betas
    walk = builtin_motion("walk", 4, 24)
    posed = pose_person(model, bare, walk.global_orient, walk.body_pose, walk.transl)
    body = model(np.tile(look_betas(model, look), (4, 1)), walk.global_orient, walk.body_pose, walk.transl)
    expected = body.vertices.double().numpy()[:, bare.body_index]
    error = np.linalg.norm(posed - expected, axis=2)
    assert error.max() < SHOE_OFFSET_M + 1e-4  # only the shoes keep a thin offset
    assert np.median(error) < 1e-5
    still = pose_person(model, bare, np.zeros(3), np.zeros(69), [0.1, 0.2, 0.3])[0]
    np.testing.assert_allclose(still, bare.rest_vertices + [0.1, 0.2, 0.3], atol=1e-6)


def test_front_and_back_differ_but_mirrored_views_do_not(model, striped):
    posed = pose_person(model, striped, np.zeros(3), np.zeros(69), np.zeros(3))[0]
    mesh = person_mesh(striped, posed)

    def shirt_difference(yaw_a, yaw_b):
        views, masks = [], []
        for yaw in (yaw_a, yaw_b):
            K, R, t = camera(yaw)
            views.append(render_meshes([mesh], K, R, t, W, H).rgb)
            masks.append(shirt_mask(striped, posed, K, R, t))
        both = masks[0] & masks[1][:, ::-1]  # the second view mirrored left-right
        assert both.sum() > 200
        return float(np.abs(views[0] - views[1][:, ::-1])[both].mean())

    assert shirt_difference(0.0, np.pi) > FRONT_BACK_MIN_DIFF
    plain = dress(model, replace(striped.look, shirt_pattern="plain", back_mark=""), TEXTURE)
    mesh = person_mesh(plain, posed)
    assert shirt_difference(0.5, -0.5) < MIRROR_MAX_DIFF


def test_back_mark_only_seen_from_behind(model, striped):
    unmarked = dress(model, replace(striped.look, back_mark=""), TEXTURE)
    posed = pose_person(model, striped, np.zeros(3), np.zeros(69), np.zeros(3))[0]
    for yaw, seen in ((np.pi, True), (0.0, False)):
        K, R, t = camera(yaw)
        with_mark = render_meshes([person_mesh(striped, posed)], K, R, t, W, H).rgb
        without = render_meshes([person_mesh(unmarked, posed)], K, R, t, W, H).rgb
        changed = int((np.abs(with_mark - without).max(axis=2) > MARK_PIXEL_DIFF).sum())
        assert (changed >= MARK_MIN_PIXELS) if seen else (changed == 0), (yaw, changed)


def test_outfits_bare_the_legs_below_the_shorts_and_change_only_the_shirts_back(model):
    from glimpse.fixtures.people import with_outfit

    look = replace(random_look(5, "neutral"), shirt_pattern="plain", back_mark="")
    shorts = dress(model, with_outfit(look, ("shorts",)), TEXTURE)
    long = dress(model, look, TEXTURE)
    joints = rest_joints(model, shorts)
    for person, bare in ((shorts, True), (long, False)):
        shins = np.isin(person.weights.argmax(1), (4, 5)) & (person.region != REGIONS.index("shoes"))
        share = (person.region[shins] == REGIONS.index("skin")).mean()
        assert share == 1.0 if bare else share < 0.3  # long trousers: skin only in the strip above the shoes
    thighs = np.isin(shorts.weights.argmax(1), (1, 2)) & (shorts.rest_vertices[:, 1] > joints[1, 1] - 0.1)
    assert (shorts.region[thighs] == REGIONS.index("trousers")).mean() > 0.9
    two_tone = dress(model, with_outfit(look, ("two_tone",)), TEXTURE)
    posed = pose_person(model, two_tone, np.zeros(3), np.zeros(69), np.zeros(3))[0]
    for yaw, differs in ((np.pi, True), (0.0, False)):  # the back panel shows from behind only
        K, R, t = camera(yaw)
        mask = shirt_mask(two_tone, posed, K, R, t)
        plain = render_meshes([person_mesh(long, posed)], K, R, t, W, H).rgb
        toned = render_meshes([person_mesh(two_tone, posed)], K, R, t, W, H).rgb
        change = float(np.abs(plain - toned).max(axis=2)[mask].mean())
        assert (change > 0.15) if differs else (change < 0.01), (yaw, change)
    with pytest.raises(ValueError, match="unknown outfit"):
        with_outfit(look, ("kilt",))
