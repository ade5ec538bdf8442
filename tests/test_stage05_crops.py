"""Stage 05's crops: the square box and padding, the soft mask, view words, hidden face keypoints,
the OpenPose drawing, then the stage on the tiny demo scene (files, keypoints on the person,
determinism, people with no usable frame; with the sds prior: no weights refused, identities
trained on tiny models)."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import torch

from glimpse.body.keypoints import keypoint_map
from glimpse.body.model import BodyModel
from glimpse.crops.box import CropBox, background_colour, crop_padded, resize_square, soft_mask, square_box
from glimpse.crops.stage import evenly_spaced, identity_plan
from glimpse.errors import ConfigError
from glimpse.fixtures.scenes import FREE_BODY, make_scene
from glimpse.io.images import read_mask, read_rgb, write_png
from glimpse.prior.skeleton import (
    FACE_KEYPOINTS,
    HEAD_JOINT,
    LIMB_SHADE,
    OPENPOSE18_COLOURS,
    OPENPOSE18_LIMBS,
    OPENPOSE18_NAMES,
    draw_skeleton,
    hidden_face,
    shown_keypoints,
)
from glimpse.prior.views import facing_azimuth_deg, view_prompt, view_word
from tests.stage_helpers import read_json, run

STAGE = "05_textual_inversion"
UPSTREAM = ("01_sfm", "02_smpl_fit", "03_masks")
# the tiny demo's people cover 60-120 pixels of its 64x48 frames: keep them, and keep their masks whole
PARAMS = f"{STAGE}.min_mask_px=50 {STAGE}.mask_erode_px=0 {STAGE}.mask_feather_px=0.5"


# ---------------------------------------------------------------- box, padding, soft mask

def test_square_box_is_centred_on_the_mask_and_holds_it():
    mask = np.zeros((60, 50), bool)
    mask[5:45, 10:30] = True  # 20 wide, 40 tall
    box = square_box(mask, 1.1)
    assert box == CropBox(-2, 3, 44)  # side ceil(1.1 * 40), centre (20, 25) in pixel-edge coordinates
    assert box.x0 <= 10 and box.x0 + box.side >= 30 and box.y0 <= 5 and box.y0 + box.side >= 45
    assert square_box(np.zeros((4, 4), bool), 1.1) is None
    # the box's centre pixel maps to the crop's centre, at any crop size
    assert np.allclose(box.to_crop(np.array([[19.5, 24.5]]), 512), [[255.5, 255.5]])


def test_crops_are_padded_outside_the_frame():
    image = np.arange(8 * 8 * 3, dtype=np.uint8).reshape(8, 8, 3) + 1
    box = CropBox(-3, 5, 6)
    crop = crop_padded(image, box, 0)
    assert crop.shape == (6, 6, 3)
    assert np.array_equal(crop[:3, 3:], image[5:8, 0:3])
    assert not crop[:, :3].any() and not crop[3:].any()  # left of and below the frame
    assert not crop_padded(image, CropBox(20, 20, 4)).any()  # wholly outside
    assert crop_padded(np.ones((8, 8), bool), box, False).sum() == 9


def test_soft_mask_erodes_feathers_and_treats_the_outside_as_not_person():
    mask = np.zeros((40, 40), bool)
    mask[10:30, 10:30] = True
    assert np.array_equal(soft_mask(mask, 0, 0), mask.astype(np.float32))
    soft = soft_mask(mask, 2.0, 1.5)
    assert soft.dtype == np.float32 and 0.0 <= soft.min() and soft.max() <= 1.0
    assert soft[20, 20] == pytest.approx(1.0, abs=1e-6) and soft[5, 5] == 0.0
    assert soft[20, 11] < 0.5 < soft[20, 12]  # the edge moved in by 2 pixels: from 9.5 to 11.5
    assert soft_mask(mask, 0, 1.5)[20, 9] < 0.5 < soft_mask(mask, 0, 1.5)[20, 10]
    edge = np.ones((20, 20), bool)  # a mask touching the array's border erodes from there too
    assert soft_mask(edge, 2.0, 0)[0].sum() == 0 and soft_mask(edge, 2.0, 0)[10, 10] == 1.0


def test_resizing_keeps_ranges_and_background_colours_are_per_crop_and_deterministic():
    mask = np.zeros((31, 31), np.float32)
    mask[10:20, 10:20] = 1.0
    for size in (16, 31, 100):
        out = resize_square(mask, size, is_mask=True)
        assert out.shape == (size, size) and out.min() >= 0 and out.max() <= 1
    image = np.full((31, 31, 3), 250.0, np.float32)
    image[15, 15] = 0.0  # bicubic overshoot near it is clipped
    assert resize_square(image, 100, is_mask=False).max() <= 255.0
    assert np.array_equal(background_colour(0, 1, 7), background_colour(0, 1, 7))
    colours = {tuple(background_colour(seed, pid, fid)) for seed in (0, 1) for pid in (0, 1) for fid in range(5)}
    assert len(colours) == 20
    assert evenly_spaced(list(range(10)), 4) == [0, 3, 6, 9] and evenly_spaced([3, 5], 0) == [3, 5]


# ---------------------------------------------------------------- views and prompts

def _turned(deg: float) -> np.ndarray:
    """Axis-angle of a turn of ``deg`` about +y (the body's up)."""
    return np.array([0.0, np.radians(deg), 0.0])


@pytest.mark.parametrize("turn, azimuth, view", [
    (0.0, 0.0, "front"), (30.0, -30.0, "front"), (90.0, -90.0, "side"), (-90.0, 90.0, "side"),
    (120.0, -120.0, "side"), (180.0, 180.0, "back"), (-150.0, 150.0, "back"),
])
def test_view_words_follow_the_angle_between_facing_and_camera(turn, azimuth, view):
    pelvis, camera = np.array([1.0, 0.9, 2.0]), np.array([1.0, 1.6, 5.0])  # camera in front (+z), above
    found = facing_azimuth_deg(_turned(turn), pelvis, camera)
    assert abs((found - azimuth + 180.0) % 360.0 - 180.0) < 1e-9  # +90: camera on the body's left (+x)
    assert view_word(found, 45.0, 135.0) == view


def test_view_is_measured_about_the_body_up_axis():
    """A body lying on its back, face up, seen from straight above: front; from its feet: side."""
    lying = np.array([-np.pi / 2, 0.0, 0.0])  # canonical up (+y) -> -z, facing (+z) -> +y
    pelvis = np.zeros(3)
    assert view_word(facing_azimuth_deg(lying, pelvis, np.array([0.0, 3.0, 0.0])), 45, 135) == "front"
    assert facing_azimuth_deg(lying, pelvis, np.array([0.0, 0.0, -3.0])) == 0.0  # along its up: no direction
    assert view_word(facing_azimuth_deg(lying, pelvis, np.array([2.0, 0.0, 0.5])), 45, 135) == "side"
    assert view_prompt("a photo of a {token} person, {view} view", "p1", "back") == \
        "a photo of a <person-p1> person, back view"


# ---------------------------------------------------------------- hidden face keypoints, drawing

@pytest.fixture(scope="module")
def body():
    model = BodyModel.from_file(FREE_BODY, dtype=torch.float64)
    return model, keypoint_map("openpose18", model.data)


def _pose(body, turn_deg: float) -> tuple[np.ndarray, np.ndarray]:
    model, kmap = body
    zeros = torch.zeros(1, 69, dtype=torch.float64)
    out = model(torch.zeros(10, dtype=torch.float64), torch.as_tensor(_turned(turn_deg))[None], zeros)
    return kmap(out.joints, out.vertices)[0].numpy(), out.joints[0].numpy()


def test_face_keypoints_are_dropped_when_the_head_turns_away(body):
    camera = np.array([0.0, 0.4, 3.0])  # in front of the canonical body (it faces +z)
    index = {name: k for k, name in enumerate(OPENPOSE18_NAMES)}

    def hidden(turn: float) -> set[str]:
        keypoints, joints = _pose(body, turn)
        return {OPENPOSE18_NAMES[k] for k in np.flatnonzero(hidden_face(keypoints, joints[HEAD_JOINT], camera))}

    assert hidden(0.0) == set()  # facing the camera: the whole face
    assert hidden(180.0) == {"nose", "right_eye", "left_eye"}  # from behind: the ears stay (level with the head)
    assert hidden(90.0) == {"left_ear", "left_eye"}  # turned to face +x: the camera sees the body's right side
    assert hidden(-90.0) == {"right_ear", "right_eye"}
    assert set(FACE_KEYPOINTS) == {index[n] for n in ("nose", "right_eye", "left_eye", "right_ear", "left_ear")}


def test_keypoints_behind_the_camera_or_far_off_the_crop_are_not_shown():
    pixels = np.array([[10.0, 10.0], [-30.0, 10.0], [10.0, 70.0], [np.nan, np.nan], [5.0, 5.0]])
    depth = np.array([2.0, 2.0, 2.0, 2.0, -1.0])
    shown = shown_keypoints(pixels, depth, np.zeros(5, bool), 64)  # a margin of 16 pixels around 64
    assert shown.tolist() == [True, False, True, False, False]


def _spread_points(size: int) -> np.ndarray:
    """18 keypoints far apart (a 6x3 grid), so no dot covers another."""
    u, v = np.meshgrid(np.linspace(40, size - 40, 3), np.linspace(40, size - 40, 6))
    return np.stack([u.ravel(), v.ravel()], 1)


def test_skeleton_draws_openpose_colours_at_keypoints_and_shaded_limbs():
    size, points = 256, _spread_points(256)
    shown = np.ones(18, bool)
    shown[4] = False  # right wrist: its dot and the elbow-wrist limb go
    canvas = draw_skeleton(points, shown, size, 4.0)
    assert canvas.shape == (size, size, 3) and canvas.dtype == np.uint8
    for k, (u, v) in enumerate(np.rint(points).astype(int)):
        expected = OPENPOSE18_COLOURS[k] if shown[k] else (0, 0, 0)
        assert tuple(canvas[v, u]) == expected, OPENPOSE18_NAMES[k]
    neck_to_hip = OPENPOSE18_LIMBS.index((1, 8))  # a limb between two shown keypoints: its shaded colour
    u, v = np.rint((points[1] + points[8]) / 2).astype(int)
    assert tuple(canvas[v, u]) == tuple(int(c * LIMB_SHADE) for c in OPENPOSE18_COLOURS[neck_to_hip])
    assert not canvas[0, 0].any()  # black elsewhere
    elbow_to_wrist = OPENPOSE18_LIMBS.index((3, 4))  # a limb is drawn only when both its ends are shown
    u, v = np.rint((points[3] + points[4]) / 2).astype(int)
    pair = np.zeros(18, bool)
    pair[[3, 4]] = True
    assert tuple(draw_skeleton(points, pair, size, 4.0)[v, u]) == \
        tuple(int(c * LIMB_SHADE) for c in OPENPOSE18_COLOURS[elbow_to_wrist])
    pair[4] = False
    assert not draw_skeleton(points, pair, size, 4.0)[v, u].any()


# ---------------------------------------------------------------- the stage on the tiny demo

@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    root = tmp_path_factory.mktemp("crops_demo")
    scene = make_scene("demo", root / "scene", "tiny", seed=0)
    for stage in UPSTREAM:
        run(stage, scene, root / "out")
    return scene, root, run(STAGE, scene, root / "out", PARAMS)


def test_stage_writes_crops_masks_skeletons_and_a_manifest(demo):
    scene, root, out = demo
    manifest = read_json(out / "manifest.json")
    summary = manifest["summary"]
    assert summary["identity"] == "skipped" and summary["prior_kind"] == "surface"  # auto without weights
    assert "only the sds prior uses an identity" in summary["identity_reason"]
    masks_doc = read_json(root / "out" / "demo_tiny" / "03_masks" / "masks.json")
    for pid in ("p0", "p1"):
        doc = read_json(out / pid / "crops" / "crops.json")
        assert manifest["formats"][f"{pid}/crops/crops.json"] == doc["format"] == "glimpse-crops/1"
        expected = [int(name) for name, frame in sorted(masks_doc["frames"].items())
                    if frame["visible_pixels"].get(pid, 0) >= 50]
        assert [c["frame"] for c in doc["crops"]] == expected and summary["people"][pid]["crops"] == len(expected)
        assert doc["token"] == f"<person-{pid}>" and len(doc["keypoint_names"]) == 18
        for crop in doc["crops"]:
            # people walking across a camera ahead of them: seen from the side
            assert crop["view"] == "side" and 45 <= abs(crop["azimuth_deg"]) <= 135
            assert crop["prompt"] == f"a photo of a <person-{pid}> person, side view"
            image, mask, skeleton = (read_rgb(out / pid / "crops" / folder / crop["file"])
                                     for folder in ("images", "masks", "skeletons"))
            assert image.shape == skeleton.shape == (512, 512, 3) and mask.shape == (512, 512, 3)
            assert tuple(image[0, 0]) == tuple(crop["background_rgb"])  # the crop's corner is background
            keypoints = np.array([k for k in crop["keypoints18"] if k[2]], float)
            assert len(keypoints) >= 14  # every limb keypoint, at least one ear
            # the skeleton has a drawn dot at every shown keypoint
            u, v = np.rint(keypoints[:, :2]).astype(int).T
            assert (skeleton[v, u].max(1) >= 170).all()
            # the projected body lies on the person: the hips' midpoint on stage 03's mask, mapped to the crop
            hips = np.array(crop["keypoints18"])[[8, 11], :2].astype(float).mean(0)
            assert mask[int(round(hips[1])), int(round(hips[0])), 0] > 128


def test_crops_follow_the_stage_03_mask_through_the_box(demo):
    """The crop's mask, brought back to the frame through its box, is stage 03's mask."""
    import cv2

    scene, root, out = demo
    doc = read_json(out / "p1" / "crops" / "crops.json")
    crop = doc["crops"][0]
    x0, y0, side = crop["box"]
    truth = read_mask(root / "out" / "demo_tiny" / "03_masks" / "masks" / "p1" / crop["file"])
    mask = read_mask(out / "p1" / "crops" / "masks" / crop["file"])
    back = cv2.resize(mask.astype(np.uint8), (side, side), interpolation=cv2.INTER_AREA).astype(bool)
    padded = crop_padded(truth, CropBox(x0, y0, side), False)
    assert padded.sum() == truth.sum()  # the box holds the whole mask
    assert (back & padded).sum() / (back | padded).sum() > 0.8


def test_stage_is_deterministic_and_reports_people_without_crops(demo, tmp_path):
    scene, root, out = demo
    twin = tmp_path / "out"
    shutil.copytree(root / "out", twin)
    again = run(STAGE, scene, twin, PARAMS)
    for pid in ("p0", "p1"):
        for path in sorted((out / pid / "crops").rglob("*.*")):
            assert path.read_bytes() == (again / path.relative_to(out)).read_bytes(), path
    none = run(STAGE, scene, twin, f"{STAGE}.min_mask_px=100000")
    for pid in ("p0", "p1"):
        assert read_json(none / pid / "crops" / "crops.json")["crops"] == []
        assert sorted(p.name for p in (none / pid / "crops").iterdir()) == ["crops.json"]
        entry = read_json(none / "manifest.json")["summary"]["people"][pid]
        assert entry["crops"] == 0 and "min_mask_px" in entry["note"]


def test_the_sds_prior_without_weights_stops_before_any_work(demo, tmp_path):
    scene, root, _ = demo
    twin = tmp_path / "out"
    shutil.copytree(root / "out", twin, ignore=shutil.ignore_patterns(STAGE))
    with pytest.raises(ConfigError, match=r"diffusion\.sd_path and diffusion\.controlnet_path"):
        run(STAGE, scene, twin, "prior.kind=sds")
    assert not (twin / "demo_tiny" / STAGE).exists()
    assert identity_plan("surface").reason.startswith("prior.kind is surface")
    assert identity_plan("sds").identity == "trained"


def test_the_sds_prior_trains_each_persons_identity_with_tiny_models(demo, tmp_path):
    pytest.importorskip("diffusers")
    from glimpse.prior.sds.guidance import DiffusionModels
    from glimpse.prior.sds.identity import load_identity
    from tests.tiny_diffusion import RENDER_PX, tiny_models, write_tiny_weights

    scene, root, _ = demo
    scene_copy, twin = tmp_path / "scene", tmp_path / "out"
    shutil.copytree(scene, scene_copy)
    reference = scene_copy / "humans" / "p0" / "reference"
    reference.mkdir()
    write_png(reference / "face.png", np.full((40, 30, 3), 200, np.uint8))  # another photo of p0
    shutil.copytree(root / "out", twin, ignore=shutil.ignore_patterns(STAGE))
    sd, controlnet = write_tiny_weights(tmp_path / "weights")
    identity = f"{STAGE}.identity"
    out = run(STAGE, scene_copy, twin,
              f"{PARAMS} prior.kind=sds diffusion.sd_path={sd} diffusion.controlnet_path={controlnet} "
              f"diffusion.allow_cpu=true {STAGE}.crop_size_px={RENDER_PX} {identity}.steps=3 {identity}.batch_size=2 "
              f"{identity}.samples.count=2 {identity}.samples.steps=2")
    manifest = read_json(out / "manifest.json")
    assert manifest["summary"]["identity"] == "trained"
    people = manifest["summary"]["people"]
    assert people["p0"]["identity"]["references"] == 1 and people["p1"]["identity"]["references"] == 0
    for pid in ("p0", "p1"):
        summary = people[pid]["identity"]
        assert summary["trained"] and summary["steps"] == 3
        assert summary["examples"] == people[pid]["crops"] + summary["references"]
        assert read_rgb(out / pid / "identity" / "samples.png").shape == (RENDER_PX, 2 * RENDER_PX, 3)
        assert manifest["formats"][f"{pid}/identity/identity.safetensors"] == "glimpse-identity/1"
        unet, cn, vae, text_encoder, tokenizer, scheduler = tiny_models(tmp_path / f"fresh_{pid}")
        fresh = DiffusionModels(unet, cn, vae, text_encoder, tokenizer, scheduler, torch.device("cpu"))
        assert load_identity(fresh, out / pid / "identity" / "identity.safetensors").token == f"<person-{pid}>"
