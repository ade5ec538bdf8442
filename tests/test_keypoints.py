"""Keypoint maps (COCO-17, OpenPose BODY-25, OpenPose-18) on SMPL-topology and free bodies."""

import numpy as np
import pytest
import torch

from glimpse.body.keypoints import LAYOUTS, SMPL_LANDMARK_VERTICES, keypoint_map
from glimpse.body.model import BodyModel
from glimpse.body.model_file import load_body_model_file
from glimpse.config import REPO_ROOT
from glimpse.errors import GlimpseError
from tests.body_files import write_random_smpl_npz

FREE_BODY = REPO_ROOT / "glimpse" / "body" / "assets" / "free_body.npz"
COCO17 = ("nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder", "right_shoulder",
          "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hip", "right_hip", "left_knee",
          "right_knee", "left_ankle", "right_ankle")


def test_layout_orders():
    assert tuple(n for n, _ in LAYOUTS["coco17"]) == COCO17
    body25 = [n for n, _ in LAYOUTS["openpose25"]]
    assert len(body25) == 25 and body25[1] == "neck" and body25[8] == "mid_hip" and body25[24] == "right_heel"
    op18 = [n for n, _ in LAYOUTS["openpose18"]]
    assert op18 == [n for n in body25[:19] if n != "mid_hip"]


def test_smpl_topology_uses_the_standard_vertex_ids(tmp_path):
    path = tmp_path / "smpl.npz"
    write_random_smpl_npz(path, seed=3)
    model = BodyModel.from_file(path, dtype=torch.float64)
    rng = np.random.default_rng(0)
    out = model(torch.as_tensor(rng.normal(size=(2, 10))), torch.as_tensor(rng.normal(0, 0.3, (2, 3))),
                torch.as_tensor(rng.normal(0, 0.2, (2, 69))), torch.as_tensor(rng.normal(size=(2, 3))))
    for layout in sorted(set(LAYOUTS) - {"coco17_skin"}):  # SMPL has no built-in limb landmarks
        kmap = keypoint_map(layout, model.data)
        kp = kmap(out.joints, out.vertices)
        names = list(kmap.names)
        assert torch.allclose(kp[:, names.index("nose")], out.vertices[:, SMPL_LANDMARK_VERTICES["nose"]])
        assert torch.allclose(kp[:, names.index("left_knee")], out.joints[:, 4])
        if "neck" in names:
            assert torch.allclose(kp[:, names.index("neck")], out.joints[:, [16, 17]].mean(1))


def test_free_body_keypoints_sit_where_they_belong():
    data = load_body_model_file(FREE_BODY)
    model = BodyModel(data, dtype=torch.float64)
    out = model(torch.zeros(1, 10, dtype=torch.float64), torch.zeros(1, 3, dtype=torch.float64),
                torch.zeros(1, 69, dtype=torch.float64))
    kmap = keypoint_map("openpose25", data)
    kp = dict(zip(kmap.names, kmap(out.joints, out.vertices)[0].numpy()))
    head = out.joints[0, 15].numpy()
    assert kp["nose"][2] > head[2] + 0.08  # in front of the head joint
    for side, sign in (("left", 1), ("right", -1)):
        assert sign * kp[f"{side}_eye"][0] > 0.01 and sign * kp[f"{side}_ear"][0] > 0.05
        assert kp[f"{side}_eye"][1] > kp["nose"][1] > kp[f"{side}_shoulder"][1]
        assert kp[f"{side}_big_toe"][2] > kp[f"{side}_ankle"][2] + 0.1 > kp[f"{side}_heel"][2] + 0.1
        assert kp[f"{side}_big_toe"][1] < kp[f"{side}_ankle"][1]
        assert abs(kp[f"{side}_big_toe"][0]) < abs(kp[f"{side}_small_toe"][0])  # big toe on the inside


def test_unknown_layout_and_missing_landmarks_are_clear(tmp_path):
    data = load_body_model_file(FREE_BODY)
    with pytest.raises(ValueError, match="unknown keypoint layout 'coco18'; known: coco17"):
        keypoint_map("coco18", data)
    path = tmp_path / "odd.npz"
    arrays = {k: v for k, v in np.load(FREE_BODY).items() if not k.startswith("landmark")}
    np.savez(path, **arrays)
    with pytest.raises(GlimpseError, match="needs landmark_names"):
        keypoint_map("coco17", load_body_model_file(path))


def test_skin_layout_sits_near_the_joints_it_annotates():
    """coco17_skin (anny's COCO regressor) lies within a few centimetres of the joint centres coco17 uses."""
    data = load_body_model_file(FREE_BODY)
    model = BodyModel(data, dtype=torch.float64)
    out = model(torch.zeros(1, 10, dtype=torch.float64), torch.zeros(1, 3, dtype=torch.float64),
                torch.zeros(1, 69, dtype=torch.float64))
    joints = keypoint_map("coco17", data)(out.joints, out.vertices)[0]
    skin = keypoint_map("coco17_skin", data)(out.joints, out.vertices)[0]
    gap = (skin - joints).norm(dim=-1)
    assert torch.allclose(gap[:5], torch.zeros(5, dtype=torch.float64))  # face points are the same landmarks
    assert 0.003 < gap[5:].min() and gap[5:].max() < 0.05
    left, right = skin[5::2], skin[6::2]
    assert (left[:, 0] > right[:, 0]).all()  # left points on the body's left (+x)


def test_skin_layout_needs_the_limb_landmarks(tmp_path):
    arrays = dict(np.load(FREE_BODY))
    keep = [k for k, n in enumerate(arrays["landmark_names"]) if "_" not in n or n.split("_")[1] in {"eye", "ear", "big", "small", "heel"}]
    for key in ("landmark_names", "landmark_indices", "landmark_weights"):
        arrays[key] = arrays[key][keep]
    path = tmp_path / "faces_only.npz"
    np.savez(path, **arrays)
    data = load_body_model_file(path)
    keypoint_map("coco17", data)  # joint-centre limbs need no limb landmarks
    with pytest.raises(GlimpseError, match="coco17_skin keypoints need the surface landmarks left_shoulder"):
        keypoint_map("coco17_skin", data)
