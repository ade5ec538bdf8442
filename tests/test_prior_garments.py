"""The surface prior's skin-or-garment anchors (glimpse.prior.garments) on the free body's rest template, painted
as a person in a short-sleeved shirt and trousers seen only from the front, with the shins never seen."""

from __future__ import annotations

import numpy as np
import pytest

from glimpse.body.symmetry import mirror_vertex_map
from glimpse.prior.complete import part_groups
from glimpse.prior.garments import LOWER, UPPER, body_zones, garment_anchors, weighted_median

SKIN, SHIRT, TROUSERS, NEUTRAL = (0.85, 0.65, 0.5), (0.2, 0.4, 0.8), (0.3, 0.25, 0.1), (0.18, 0.18, 0.2)
FOREARMS, UPPER_ARMS, SHINS = (18, 19), (16, 17), (4, 5)
PARAMS = {"skin_colour_distance": 0.15, "skin_reach_m": 0.12, "neutral_garment": np.array(NEUTRAL)}


@pytest.fixture(scope="module")
def body():
    data = np.load("glimpse/body/assets/free_body.npz")
    vertices = data["v_template"].astype(np.float64)
    labels = data["weights"].argmax(1)
    mirror, _ = mirror_vertex_map(vertices)
    return vertices, labels, part_groups(labels, mirror), body_zones(labels, vertices)


def painted(vertices, labels, zones, legs_seen: bool = True):
    """Colours [V, 3] and which vertices are known: the front half of the body (z above the median of its part),
    skin on the face, hands and forearms, a shirt on the torso and upper arms, trousers on the legs."""
    colours = np.tile(np.array(SHIRT), (len(vertices), 1))
    colours[zones.zone == LOWER] = TROUSERS
    colours[zones.skin_anchor | np.isin(labels, FOREARMS)] = SKIN
    front = np.zeros(len(vertices), bool)
    for label in np.unique(labels):
        rows = labels == label
        front[rows] = vertices[rows, 2] > np.median(vertices[rows, 2])
    known = front & ~np.isin(labels, SHINS)
    if not legs_seen:
        known &= zones.zone != LOWER
    return colours, known


def test_unseen_vertices_continue_skin_on_bare_limbs_and_garments_elsewhere(body):
    vertices, labels, groups, zones = body
    colours, known = painted(vertices, labels, zones)
    part_anchors = np.full((len(vertices), 3), 0.5)
    anchors = garment_anchors(colours, known, np.ones(len(vertices)), zones, groups, part_anchors, **PARAMS)
    back = ~known
    forearm_backs = back & np.isin(labels, FOREARMS)
    assert np.abs(anchors[forearm_backs] - SKIN).max() < 0.05  # skin was seen on the same limb, nearby
    torso_back = back & (labels == 9)
    assert np.allclose(anchors[torso_back], SHIRT, atol=1e-6)
    assert np.allclose(anchors[back & np.isin(labels, SHINS)], TROUSERS, atol=1e-6)  # no shin seen: the garment
    assert np.allclose(anchors[back & np.isin(labels, UPPER_ARMS) & (np.abs(vertices[:, 0]) < 0.25)], SHIRT,
                       atol=1e-6)
    other = zones.zone == 0
    assert np.array_equal(anchors[other], part_anchors[other])  # head, hands, feet keep their part means
    assert np.abs(weighted_median(colours[zones.skin_anchor & known], np.ones(int((zones.skin_anchor & known).sum())))
                  - SKIN).max() < 1e-9


def test_an_unseen_lower_body_gets_a_neutral_garment_and_no_face_means_no_decision(body):
    vertices, labels, groups, zones = body
    colours, known = painted(vertices, labels, zones, legs_seen=False)
    part_anchors = np.full((len(vertices), 3), 0.5)
    anchors = garment_anchors(colours, known, np.ones(len(vertices)), zones, groups, part_anchors, **PARAMS)
    assert np.allclose(anchors[zones.zone == LOWER], NEUTRAL)
    assert np.allclose(anchors[(zones.zone == UPPER) & ~known & (labels == 9)], SHIRT)
    faceless = known & ~zones.skin_anchor
    same = garment_anchors(colours, faceless, np.ones(len(vertices)), zones, groups, part_anchors, **PARAMS)
    assert np.array_equal(same, part_anchors)


def test_zones_cover_the_body_once_and_the_face_is_at_the_front(body):
    vertices, labels, _, zones = body
    assert set(np.unique(zones.zone)) == {0, UPPER, LOWER}
    face = zones.skin_anchor & (labels == 15)
    head = labels == 15
    assert face.any() and vertices[face, 2].mean() > vertices[head, 2].mean()
    assert np.allclose(zones.folded[:, 0], np.abs(vertices[:, 0]))
