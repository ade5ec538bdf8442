"""Keypoints of the body in the layouts detectors and ControlNet use: COCO-17,
OpenPose BODY-25 and OpenPose-18, COCO-17 as annotators mark it on the skin, and
CMU Panoptic's 19 3D keypoints ("coco19").

A keypoint is either a combination of the body's posed joints (shoulders,
elbows, wrists, hips, knees, ankles, neck, mid-hip) or a surface landmark: a
weighted set of vertices (nose, eyes, ears, toes, heels). Choices:

- Limb keypoints are SMPL's joint centres. COCO annotates the skin's bony
  landmarks instead; on the free body, anny's COCO regressor puts them within
  0.6-3.4 cm of these joints (hips 3.4 cm, 2.5 cm lower; shoulders 3.2 cm).
- Neck (OpenPose) = the midpoint of the shoulder joints, as OpenPose places it
  (SMPL's own neck joint sits about 10 cm higher, at the base of the skull).
- Mid-hip (BODY-25) = the midpoint of the hip joints.
- Landmarks: for the official SMPL topology the vertex ids used across the
  field (smplx's ``vertex_ids``); for the free body, anny's COCO whole-body
  keypoint regressor, stored in the model file by tools/make_free_body.py.
- ``coco17_skin``: all seventeen COCO points as surface landmarks (the free
  body's file carries the limb points too). This is what a keypoint detector
  trained on human annotations returns, so detectors are measured against it;
  SMPL's topology has no built-in limb landmarks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from glimpse.body.model_file import NUM_JOINTS, BodyModelData
from glimpse.errors import GlimpseError

LANDMARK_NAMES = ("nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_big_toe", "left_small_toe",
                  "left_heel", "right_big_toe", "right_small_toe", "right_heel")
SMPL_VERTEX_COUNT = 6890
# Landmark vertex ids on SMPL's 6,890-vertex topology (as in smplx's vertex_ids.py).
SMPL_LANDMARK_VERTICES = {"nose": 332, "right_eye": 6260, "left_eye": 2800, "right_ear": 4071, "left_ear": 583,
                          "left_big_toe": 3216, "left_small_toe": 3226, "left_heel": 3387,
                          "right_big_toe": 6617, "right_small_toe": 6624, "right_heel": 6787}

# SMPL joint indices
PELVIS, L_HIP, R_HIP, L_KNEE, R_KNEE, L_ANKLE, R_ANKLE = 0, 1, 2, 4, 5, 7, 8
L_SHOULDER, R_SHOULDER, L_ELBOW, R_ELBOW, L_WRIST, R_WRIST = 16, 17, 18, 19, 20, 21

# A keypoint is a joint index, a (joint, joint) midpoint, or a landmark name.
Source = int | tuple[int, int] | str
NECK: Source = (L_SHOULDER, R_SHOULDER)
MID_HIP: Source = (L_HIP, R_HIP)

COCO17_ENTRIES: tuple[tuple[str, Source], ...] = (
    ("nose", "nose"), ("left_eye", "left_eye"), ("right_eye", "right_eye"), ("left_ear", "left_ear"),
    ("right_ear", "right_ear"), ("left_shoulder", L_SHOULDER), ("right_shoulder", R_SHOULDER),
    ("left_elbow", L_ELBOW), ("right_elbow", R_ELBOW), ("left_wrist", L_WRIST), ("right_wrist", R_WRIST),
    ("left_hip", L_HIP), ("right_hip", R_HIP), ("left_knee", L_KNEE), ("right_knee", R_KNEE),
    ("left_ankle", L_ANKLE), ("right_ankle", R_ANKLE),
)

LAYOUTS: dict[str, tuple[tuple[str, Source], ...]] = {
    "coco17": COCO17_ENTRIES,
    "coco17_skin": tuple((name, name) for name, _ in COCO17_ENTRIES),
    "openpose25": (
        ("nose", "nose"), ("neck", NECK), ("right_shoulder", R_SHOULDER), ("right_elbow", R_ELBOW),
        ("right_wrist", R_WRIST), ("left_shoulder", L_SHOULDER), ("left_elbow", L_ELBOW), ("left_wrist", L_WRIST),
        ("mid_hip", MID_HIP), ("right_hip", R_HIP), ("right_knee", R_KNEE), ("right_ankle", R_ANKLE),
        ("left_hip", L_HIP), ("left_knee", L_KNEE), ("left_ankle", L_ANKLE), ("right_eye", "right_eye"),
        ("left_eye", "left_eye"), ("right_ear", "right_ear"), ("left_ear", "left_ear"),
        ("left_big_toe", "left_big_toe"), ("left_small_toe", "left_small_toe"), ("left_heel", "left_heel"),
        ("right_big_toe", "right_big_toe"), ("right_small_toe", "right_small_toe"), ("right_heel", "right_heel"),
    ),
    # CMU Panoptic's 3D body keypoints (panoptic-toolbox's README, "coco19"): not OpenPose's order
    "coco19": (
        ("neck", NECK), ("nose", "nose"), ("mid_hip", MID_HIP), ("left_shoulder", L_SHOULDER),
        ("left_elbow", L_ELBOW), ("left_wrist", L_WRIST), ("left_hip", L_HIP), ("left_knee", L_KNEE),
        ("left_ankle", L_ANKLE), ("right_shoulder", R_SHOULDER), ("right_elbow", R_ELBOW), ("right_wrist", R_WRIST),
        ("right_hip", R_HIP), ("right_knee", R_KNEE), ("right_ankle", R_ANKLE), ("left_eye", "left_eye"),
        ("left_ear", "left_ear"), ("right_eye", "right_eye"), ("right_ear", "right_ear"),
    ),
    "openpose18": (
        ("nose", "nose"), ("neck", NECK), ("right_shoulder", R_SHOULDER), ("right_elbow", R_ELBOW),
        ("right_wrist", R_WRIST), ("left_shoulder", L_SHOULDER), ("left_elbow", L_ELBOW), ("left_wrist", L_WRIST),
        ("right_hip", R_HIP), ("right_knee", R_KNEE), ("right_ankle", R_ANKLE), ("left_hip", L_HIP),
        ("left_knee", L_KNEE), ("left_ankle", L_ANKLE), ("right_eye", "right_eye"), ("left_eye", "left_eye"),
        ("right_ear", "right_ear"), ("left_ear", "left_ear"),
    ),
}


@dataclass(frozen=True)
class KeypointMap:
    """keypoints = joint_weights @ joints + sum_m vertex_weights[:, m] * vertices[vertex_indices[:, m]].

    names:          (K,) keypoint names in layout order
    joint_weights:  (K, 24)
    vertex_indices: (K, M) int64 (padded with 0 where the weight is 0)
    vertex_weights: (K, M); each row sums to 1 for a landmark, 0 for a joint keypoint
    """

    layout: str
    names: tuple[str, ...]
    joint_weights: np.ndarray
    vertex_indices: np.ndarray
    vertex_weights: np.ndarray

    def __call__(self, joints: Tensor, vertices: Tensor) -> Tensor:
        """joints [B, 24, 3], vertices [B, V, 3] (posed) -> keypoints [B, K, 3]."""
        jw = torch.as_tensor(self.joint_weights, dtype=joints.dtype, device=joints.device)
        vw = torch.as_tensor(self.vertex_weights, dtype=vertices.dtype, device=vertices.device)
        idx = torch.as_tensor(self.vertex_indices, device=vertices.device)
        from_joints = torch.einsum("kj,bjd->bkd", jw, joints)
        from_vertices = torch.einsum("km,bkmd->bkd", vw, vertices[:, idx])
        return from_joints + from_vertices


def body_landmarks(data: BodyModelData) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Landmark name -> (vertex indices, weights summing to 1) for this model file."""
    extras = data.extras
    if "landmark_names" in extras:
        names = [str(n) for n in extras["landmark_names"]]
        return {
            name: (extras["landmark_indices"][k][extras["landmark_weights"][k] > 0].astype(np.int64),
                   extras["landmark_weights"][k][extras["landmark_weights"][k] > 0].astype(np.float64))
            for k, name in enumerate(names)
        }
    if len(data.v_template) == SMPL_VERTEX_COUNT:
        return {name: (np.array([vid]), np.ones(1)) for name, vid in SMPL_LANDMARK_VERTICES.items()}
    raise GlimpseError(
        f"{data.source}: a model with {len(data.v_template)} vertices needs landmark_names / landmark_indices / "
        f"landmark_weights (face and foot keypoints); only SMPL's {SMPL_VERTEX_COUNT}-vertex topology has built-in ones"
    )


def keypoint_map(layout: str, data: BodyModelData) -> KeypointMap:
    """The keypoint map of ``layout`` (coco17 | coco17_skin | coco19 | openpose25 | openpose18) for a body model
    file."""
    if layout not in LAYOUTS:
        raise ValueError(f"unknown keypoint layout {layout!r}; known: {', '.join(LAYOUTS)}")
    return _entries_map(layout, LAYOUTS[layout], data)


def landmark_map(name: str, landmark_names: tuple[str, ...], data: BodyModelData) -> KeypointMap:
    """A map of surface landmarks only (for example the soles a fit stands on), called ``name``."""
    return _entries_map(name, tuple((n, n) for n in landmark_names), data)


def _entries_map(layout: str, entries: tuple[tuple[str, Source], ...], data: BodyModelData) -> KeypointMap:
    landmarks = body_landmarks(data)
    missing = [s for _, s in entries if isinstance(s, str) and s not in landmarks]
    if missing:
        raise GlimpseError(f"{data.source}: the {layout} keypoints need the surface landmarks {', '.join(missing)}, "
                           "which this body model file does not carry (the free body has them)")
    width = max(len(landmarks[s][0]) for _, s in entries if isinstance(s, str))
    joint_weights = np.zeros((len(entries), NUM_JOINTS))
    vertex_indices = np.zeros((len(entries), width), np.int64)
    vertex_weights = np.zeros((len(entries), width))
    for k, (_, source) in enumerate(entries):
        if isinstance(source, str):
            idx, w = landmarks[source]
            vertex_indices[k, : len(idx)], vertex_weights[k, : len(idx)] = idx, w
        elif isinstance(source, tuple):
            joint_weights[k, list(source)] = 1.0 / len(source)
        else:
            joint_weights[k, source] = 1.0
    return KeypointMap(layout, tuple(name for name, _ in entries), joint_weights, vertex_indices, vertex_weights)
