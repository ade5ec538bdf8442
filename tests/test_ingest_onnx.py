"""The ingest's plumbing for models the user brings (glimpse.ingest.onnx_models), on tiny ONNX graphs built here
in the layouts rtmlib and mmdeploy export: a detector that boxes the bright part of its input (end-to-end
``dets``/``labels``), SimCC and heatmap pose models whose every keypoint is the brightest pixel of their input
(tests/tiny_onnx.py). Where such a model says a thing is must be where it is in the image: letterbox, crops,
bins and cells."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from glimpse.errors import GlimpseError
from glimpse.ingest.onnx_models import (
    OnnxDetector,
    OnnxPose,
    box_to_input,
    decode_heatmaps,
    decode_simcc,
    decode_yolox,
    letterbox,
)
from tests.tiny_onnx import (
    DET_SIZE,
    POSE_H,
    bright_box_detector,
    brightest_point_pose,
)


def test_letterbox_keeps_the_aspect_ratio_at_the_top_left() -> None:
    image = np.full((30, 60, 3), 200, np.uint8)
    boxed, ratio = letterbox(image, 96, 96)
    assert ratio == pytest.approx(1.6) and (boxed[:48] == 200).all() and (boxed[48:] == 114).all()


def test_detector_boxes_land_on_the_image(tmp_path: Path) -> None:
    model = bright_box_detector(tmp_path / "det.onnx")
    image = np.full((120, 200, 3), 40, np.uint8)
    image[30:90, 120:150] = 250  # a bright person-sized box
    for kind in ("rtmdet", "yolox"):
        boxes, scores = OnnxDetector(model, kind, 0.5)(image)
        assert boxes.shape == (1, 4) and scores.tolist() == [1.0]
        np.testing.assert_allclose(boxes[0], [120, 30, 149, 89], atol=200 / DET_SIZE)  # one input pixel


@pytest.mark.parametrize(("count", "simcc"), [(17, True), (133, True), (17, False)],
                         ids=["rtmpose-coco17", "dwpose-wholebody", "vitpose-heatmap"])
def test_pose_keypoints_land_on_the_image(tmp_path: Path, count: int, simcc: bool) -> None:
    model = brightest_point_pose(tmp_path / "pose.onnx", count, simcc)
    image = np.full((300, 400, 3), 30, np.uint8)
    dot = (231, 143)  # x, y
    image[dot[1] - 1: dot[1] + 2, dot[0] - 1: dot[0] + 2] = 255
    box = np.array([180.0, 60.0, 260.0, 260.0])
    points, scores = OnnxPose(model, 1.25)(image, box)
    assert points.shape == (17, 2) and scores.shape == (17,)
    pixel = 250 / POSE_H  # image pixels per input pixel (box height 200 x 1.25)
    tolerance = (1.0 if simcc else 2.5) * pixel  # a SimCC bin is half an input pixel; a heatmap cell four
    np.testing.assert_allclose(points, np.tile(dot, (17, 1)), atol=tolerance)


def test_box_to_input_centres_the_box_and_keeps_the_aspect() -> None:
    affine = box_to_input(np.array([10.0, 20.0, 50.0, 220.0]), 64, 48, 1.0)
    centre = affine[:, :2] @ [(48 - 1) / 2, (64 - 1) / 2] + affine[:, 2]
    np.testing.assert_allclose(centre, [30, 120])
    assert affine[0, 0] == pytest.approx(affine[1, 1])  # the box is widened, not stretched


def test_decoders_on_hand_made_outputs() -> None:
    simcc_x, simcc_y = np.zeros((2, 96)), np.zeros((2, 128))
    simcc_x[:, 41], simcc_y[:, 77] = 0.9, 0.6
    points, scores = decode_simcc(simcc_x, simcc_y, width=48)
    np.testing.assert_allclose(points, [[20.5, 38.5]] * 2)
    np.testing.assert_allclose(scores, [0.6, 0.6])
    heat = np.zeros((1, 16, 12))
    heat[0, 5, 7], heat[0, 5, 8] = 1.0, 0.5
    points, scores = decode_heatmaps(heat, 64, 48)
    np.testing.assert_allclose(points, [[(7.25 + 0.5) * 4 - 0.5, (5 + 0.5) * 4 - 0.5]])
    raw = np.zeros((12 * 12 + 6 * 6 + 3 * 3, 6))
    raw[:, 2:4] = np.log(2.0)  # every box 2 strides wide
    raw[14, :] = [0.5, 0.25, np.log(4.0), np.log(8.0), 0.9, 0.8]  # grid cell (2, 1) at stride 8
    boxes, scores = decode_yolox(raw, 96, 96, min_score=0.5)
    np.testing.assert_allclose(boxes, [[(2.5 * 8) - 16, (1.25 * 8) - 32, (2.5 * 8) + 16, (1.25 * 8) + 32]])
    np.testing.assert_allclose(scores, [0.72])


def test_missing_user_models_are_named(tmp_path: Path) -> None:
    with pytest.raises(GlimpseError, match="pose_onnx_path is not set"):
        OnnxPose(None, 1.25)
    with pytest.raises(GlimpseError, match="no such ONNX detector model"):
        OnnxDetector(str(tmp_path / "nothing.onnx"), "rtmdet", 0.5)
