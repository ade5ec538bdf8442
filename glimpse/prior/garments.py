"""Skin or garment: what the completion continues where no view saw the body (prior_surface.garments).

The surface prior completes unseen vertices towards an anchor colour (glimpse.prior.complete). With
garments on, the anchor of a vertex on the torso, arms or legs is the colour of the *class* a person most
likely has there, not the mean of everything seen on its body part (a short sleeve's upper arm is half
shirt, half skin; its mean is neither):

1. The person's skin colour is the opacity-weighted median colour of the seen face (the front of the head)
   and hands, which people rarely cover. Not seen: no decision, the part means stay.
2. A seen vertex is skin when its colour lies within ``skin_colour_distance`` (RGB, 0-1) of that skin
   colour; else it is garment. Garment colours are pooled in two zones: the upper body (torso, arms) and the
   lower body (pelvis, legs).
3. An unseen vertex takes skin only where skin was seen nearby on the same limb: its nearest seen vertex on
   its body part (left and right folded together, so a limb seen on one side speaks for the other) is
   skin and lies within ``skin_reach_m``. Otherwise it takes its zone's seen garment colour; a zone where
   only skin was seen continues skin (bare); a lower body of which nothing was seen takes
   ``neutral_garment`` (a dark garment: people rarely show bare legs where a camera did not see them), an
   upper body of which nothing was seen the lower one's.

Head, neck, hands and feet keep their part means (hair, faces and shoes are not garments). Assumptions:
a garment colour unlike the skin (a skin-coloured shirt reads as skin), one garment per zone (a jacket over a
shirt averages), and clothes that are left-right symmetric. Units: canonical metres, RGB in [0, 1].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

# SMPL's 24 joints (the free body shares the layout): which label (weights.argmax) belongs to which zone
HEAD_JOINT = 15
HAND_JOINTS = (20, 21, 22, 23)  # wrists (the palm) and hands
UPPER_JOINTS = (3, 6, 9, 13, 14, 16, 17, 18, 19)  # spine, collars, shoulders (upper arms), elbows (forearms)
LOWER_JOINTS = (0, 1, 2, 4, 5)  # pelvis, hips (thighs), knees (shins)
OTHER, UPPER, LOWER = 0, 1, 2
FACE_DEPTH_SHARE = 0.5  # head vertices in the front half of the head's depth (canonical +z) are the face


@dataclass(frozen=True)
class BodyZones:
    """Per vertex [V]: ``zone`` (OTHER, UPPER or LOWER), ``skin_anchor`` (face or hand: skin whatever the
    clothes) and ``folded`` [V, 3], canonical positions with x folded to |x| (left and right together)."""

    zone: np.ndarray
    skin_anchor: np.ndarray
    folded: np.ndarray


def body_zones(labels: np.ndarray, canonical: np.ndarray) -> BodyZones:
    """The zones of a body from its vertices' joint labels [V] and canonical positions [V, 3] (y up, facing +z,
    left and right mirrored in x)."""
    zone = np.full(len(labels), OTHER)
    zone[np.isin(labels, UPPER_JOINTS)] = UPPER
    zone[np.isin(labels, LOWER_JOINTS)] = LOWER
    head = labels == HEAD_JOINT
    skin_anchor = np.isin(labels, HAND_JOINTS)
    if head.any():
        depth = canonical[head, 2]
        front = depth.min() + (1.0 - FACE_DEPTH_SHARE) * (depth.max() - depth.min())
        skin_anchor |= head & (canonical[:, 2] >= front)
    folded = canonical.copy()
    folded[:, 0] = np.abs(folded[:, 0])
    return BodyZones(zone, skin_anchor, folded)


def weighted_median(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """[C] the per-channel weighted median of values [N, C] with weights [N] (> 0 somewhere)."""
    out = np.empty(values.shape[1])
    for channel in range(values.shape[1]):
        order = np.argsort(values[:, channel])
        cumulative = np.cumsum(weights[order])
        out[channel] = values[order[np.searchsorted(cumulative, 0.5 * cumulative[-1])], channel]
    return out


def garment_anchors(colours: np.ndarray, known: np.ndarray, weights: np.ndarray, zones: BodyZones,
                    groups: np.ndarray, part_anchors: np.ndarray, skin_colour_distance: float, skin_reach_m: float,
                    neutral_garment: np.ndarray) -> np.ndarray:
    """[V, 3] anchor colours (see the module docstring): colours [V, 3] of the vertices, ``known`` [V] where
    they are data, ``weights`` [V] their opacity, ``groups`` [V] the body part of each vertex (mirror parts
    share one), ``part_anchors`` [V, 3] the part means the head, hands and feet keep (and every vertex when
    no face or hand was seen)."""
    anchors = part_anchors.copy()
    skin_known = known & zones.skin_anchor & (weights > 0)
    if not skin_known.any():
        return anchors
    skin = weighted_median(colours[skin_known], weights[skin_known])
    is_skin = known & ((np.linalg.norm(colours - skin, axis=1) < skin_colour_distance) | zones.skin_anchor)
    garment = {}
    for zone in (LOWER, UPPER):
        rows = known & ~is_skin & (zones.zone == zone) & (weights > 0)
        if rows.any():
            garment[zone] = (colours[rows] * weights[rows, None]).sum(0) / weights[rows].sum()
        elif (known & (zones.zone == zone)).any():
            garment[zone] = skin  # only skin seen in the zone: bare (a bare torso's back is bare too)
    garment.setdefault(LOWER, np.asarray(neutral_garment, np.float64))
    garment.setdefault(UPPER, garment[LOWER])
    for group in np.unique(groups[zones.zone != OTHER]):
        members = np.flatnonzero((groups == group) & (zones.zone != OTHER))
        seen = members[known[members]]
        skin_near = np.zeros(len(members), bool)
        if len(seen):
            distance, nearest = cKDTree(zones.folded[seen]).query(zones.folded[members])
            skin_near = is_skin[seen[nearest]] & (distance <= skin_reach_m)
        for zone in (UPPER, LOWER):
            in_zone = zones.zone[members] == zone
            anchors[members[in_zone & skin_near]] = skin
            anchors[members[in_zone & ~skin_near]] = garment[zone]
    return anchors
