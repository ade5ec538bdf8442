"""How well an ingest found the people, against ground truth (the fixture scenes'): per true person,
detection recall, identity switches, 2D keypoint PCK and mask IoU.

In each frame the found people are matched to the true ones by mask IoU (Hungarian method, pairs above
``MATCH_MIN_IOU``). Counted over the frames where the true person is at least half visible (half of the
COCO-17 joints inside the image and on the person's own visible pixels):

- recall: the fraction of those frames in which someone found is matched to the person;
- switches: how often the found id matched to the person changes from one matched frame to the next;
- PCK: the fraction of the joints in view found (confidence > 0) within ``pck_fraction`` of the torso size
  (left shoulder to right hip) of the true joint. A joint is in view when it is visible (as above) and not
  behind the person's own body either (``in_front_of_own_body``: the far arm of someone seen side-on lies on
  their visible pixels, but the camera does not see it, and the ingest is asked not to invent it). As the mask
  IoU does, it counts a frame where nobody was matched to the person, with all its joints in view not found (so
  finding a person by their mask alone, without keypoints, costs no PCK against not finding them). PCK over every visible
  joint, the far arm included, is given too (``pck_silhouette``);
- hidden reported: the fraction of joints behind the person's own body that were given a confidence > 0;
- outside reported: the fraction of the joints outside the image that were given a confidence > 0;
- mask IoU: found mask against the true visible mask (0 where nobody was matched).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise

import numpy as np
from scipy.optimize import linear_sum_assignment

from glimpse.ingest.crop import outside_image

MATCH_MIN_IOU = 0.3
HALF_VISIBLE = 0.5
TORSO_JOINTS = (5, 12)  # COCO-17 left shoulder, right hip


@dataclass(frozen=True)
class TruePerson:
    mask: np.ndarray  # [H, W] bool visible pixels
    joints: np.ndarray  # [17, 2] pixels
    visible: np.ndarray  # [17] bool: inside the image and on the person's visible pixels
    in_view: np.ndarray | None = None  # [17] bool: visible and not behind the person's own body (None: = visible)

    @property
    def seen(self) -> np.ndarray:
        return self.visible if self.in_view is None else self.visible & self.in_view


@dataclass(frozen=True)
class FoundPerson:
    mask: np.ndarray  # [H, W] bool
    keypoints: np.ndarray  # [17, 3] pixels and confidence (0 = missing)


@dataclass(frozen=True)
class PersonScore:
    frames: int  # frames where the person is at least half visible
    recall: float
    switches: int
    pck: float  # over the joints in view
    pck_silhouette: float  # over every visible joint, those behind the person's own body included
    hidden_reported: float  # share of the joints behind the person's own body given a confidence > 0
    outside_reported: float  # share of the joints outside the image given a confidence > 0 (nan: none outside)
    mask_iou: float
    ids: tuple[str, ...]  # found ids matched to the person, in order of first match


def mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two [H, W] bool masks; 0 when both are empty."""
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 0.0


def match_frame(truth: dict[str, TruePerson], found: dict[str, FoundPerson]) -> dict[str, tuple[str, float]]:
    """True pid -> (found pid, mask IoU) for one frame."""
    true_ids, found_ids = list(truth), list(found)
    if not true_ids or not found_ids:
        return {}
    iou = np.array([[mask_iou(truth[t].mask, found[f].mask) for f in found_ids] for t in true_ids])
    rows, cols = linear_sum_assignment(-iou)
    return {true_ids[r]: (found_ids[c], float(iou[r, c])) for r, c in zip(rows, cols) if iou[r, c] >= MATCH_MIN_IOU}


def in_front_of_own_body(joint_depth: np.ndarray, front_depth: np.ndarray, depth_under_skin: np.ndarray,
                         margin: float) -> np.ndarray:
    """[J] bool: joints the camera sees past the person's own body. joint_depth [J] camera z of each joint,
    front_depth [J] the person's nearest surface depth at the joint's pixel (0 or less: no surface there),
    depth_under_skin [J] how far each joint lies under the body's surface (distance to its nearest vertex),
    all in metres. A joint is in front when it lies no deeper behind that surface than under its own skin
    (+ ``margin`` for clothing and the skin's curvature); a far arm behind the chest is deeper by the
    chest's thickness."""
    no_surface = front_depth <= 0
    return no_surface | (joint_depth <= front_depth + depth_under_skin + margin)


def pck(joints: np.ndarray, visible: np.ndarray, keypoints: np.ndarray, fraction: float) -> tuple[int, int]:
    """(correct, counted) visible joints within ``fraction`` of the torso size."""
    torso = np.linalg.norm(joints[TORSO_JOINTS[0]] - joints[TORSO_JOINTS[1]])
    error = np.linalg.norm(keypoints[:, :2] - joints, axis=1)
    correct = visible & (keypoints[:, 2] > 0) & (error <= fraction * torso)
    return int(correct.sum()), int(visible.sum())


def reported(joints: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
    """joints: (J,) bool, a set of joints; keypoints: (J, 3) x, y, confidence. Returns (how many of the set were
    given a confidence > 0, how many the set holds)."""
    return np.array([np.count_nonzero(joints & (keypoints[:, 2] > 0)), np.count_nonzero(joints)])


def score_people(truth: dict[int, dict[str, TruePerson]], found: dict[int, dict[str, FoundPerson]],
                 pck_fraction: float) -> dict[str, PersonScore]:
    """truth, found: frame id -> pid -> person. Returns true pid -> score (see the module docstring)."""
    tallies: dict[str, dict] = {}
    for frame_id in sorted(truth):
        matches = match_frame(truth[frame_id], found.get(frame_id, {}))
        for pid, person in truth[frame_id].items():
            if person.visible.mean() < HALF_VISIBLE:
                continue
            tally = tallies.setdefault(pid, {"frames": 0, "hit": 0, "ids": [], "correct": 0, "counted": 0, "iou": 0.0,
                                             "silhouette": np.zeros(2), "hidden": np.zeros(2),
                                             "outside": np.zeros(2)})
            tally["frames"] += 1
            if pid not in matches:
                tally["counted"] += int(person.seen.sum())
                tally["silhouette"][1] += int(person.visible.sum())
                continue
            found_id, iou = matches[pid]
            tally["hit"] += 1
            tally["iou"] += iou
            tally["ids"].append(found_id)
            keypoints = found[frame_id][found_id].keypoints
            correct, counted = pck(person.joints, person.seen, keypoints, pck_fraction)
            tally["correct"] += correct
            tally["counted"] += counted
            tally["silhouette"] += pck(person.joints, person.visible, keypoints, pck_fraction)
            tally["hidden"] += reported(person.visible & ~person.seen, keypoints)
            tally["outside"] += reported(outside_image(person.joints, person.mask.shape), keypoints)
    scores = {}
    for pid, t in sorted(tallies.items()):
        ids = t["ids"]
        scores[pid] = PersonScore(
            frames=t["frames"], recall=t["hit"] / t["frames"],
            switches=sum(a != b for a, b in pairwise(ids)),
            pck=t["correct"] / t["counted"] if t["counted"] else 0.0,
            pck_silhouette=t["silhouette"][0] / t["silhouette"][1] if t["silhouette"][1] else 0.0,
            hidden_reported=t["hidden"][0] / t["hidden"][1] if t["hidden"][1] else 0.0,
            outside_reported=t["outside"][0] / t["outside"][1] if t["outside"][1] else float("nan"),
            mask_iou=t["iou"] / t["frames"],
            ids=tuple(dict.fromkeys(ids)))
    return scores
