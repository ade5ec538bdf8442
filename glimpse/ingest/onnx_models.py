"""Models the user brings, run on onnxruntime: a person detector and a top-down pose model, in the layouts that
rtmlib and mmdeploy export (ingest.detector / ingest.pose = onnx; docs/ingest.md).

- Detector, ``rtmdet`` (RTMDet: BGR input normalised by mmdet's mean and std) or ``yolox`` (YOLOX: BGR input,
  raw 0-255): the frame letterboxed into the model's input (top-left aligned, padded with grey 114). Output
  either mmdeploy's end-to-end pair ``dets`` [1, N, 5] (x0, y0, x1, y1, score in input pixels) and ``labels``
  [1, N], or YOLOX's raw head [1, A, 5 + C] (centre offsets and log sizes per grid cell of strides 8, 16, 32,
  objectness, class scores), decoded here. Class 0 is the person.
- Pose, RTMPose / DWPose (SimCC: ``simcc_x`` [1, K, W r], ``simcc_y`` [1, K, H r]) or ViTPose-style heatmaps
  [1, K, h, w]; K = 17 (COCO-17) or 133 (COCO-WholeBody, whose first 17 are COCO-17). Input: the person's box
  grown by ``box_padding``, widened to the model's aspect ratio, resampled to the model's input size, RGB
  normalised by ImageNet's mean and std (mmpose's convention).

Coordinates: pixel centres at integers in the image and in the model's input; a SimCC bin b is input
coordinate b / r, a heatmap cell c is input coordinate (c + 0.5) * stride - 0.5.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from glimpse.errors import GlimpseError
from glimpse.ingest.blazepose import box_iou

LETTERBOX_GREY = 114
RTMDET_MEAN_BGR = (103.53, 116.28, 123.675)
RTMDET_STD_BGR = (57.375, 57.12, 58.395)
IMAGENET_MEAN_RGB = (123.675, 116.28, 103.53)
IMAGENET_STD_RGB = (58.395, 57.12, 57.375)
YOLOX_STRIDES = (8, 16, 32)
YOLOX_NMS_IOU = 0.45
PERSON_CLASS = 0
COCO17 = 17
WHOLEBODY = 133
HEATMAP_SUBPIXEL = 0.25  # the classic quarter-pixel step towards the higher neighbour


def _session(path: str | None, what: str, threads: int):
    import onnxruntime

    if not path:
        raise GlimpseError(f"ingest.{what}_onnx_path is not set: give the path of your ONNX {what} model "
                           f"(or set ingest.{what}: blazepose)")
    if not Path(path).is_file():
        raise GlimpseError(f"{path}: no such ONNX {what} model (ingest.{what}_onnx_path); Glimpse never downloads "
                           "models, export yours with rtmlib or mmdeploy")
    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = threads
    return onnxruntime.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def _input_hw(session, what: str) -> tuple[int, int]:
    shape = session.get_inputs()[0].shape
    if len(shape) != 4 or not all(isinstance(v, int) for v in shape[2:]):
        raise GlimpseError(f"the ONNX {what} model's input must be [1, 3, H, W] with fixed H and W, found {shape}")
    return int(shape[2]), int(shape[3])


def letterbox(image: np.ndarray, height: int, width: int) -> tuple[np.ndarray, float]:
    """[H, W, 3] -> ([height, width, 3] with the image scaled to fit at the top left, grey padding; its scale)."""
    ratio = min(height / image.shape[0], width / image.shape[1])
    size = (max(1, round(image.shape[1] * ratio)), max(1, round(image.shape[0] * ratio)))
    out = np.full((height, width, 3), LETTERBOX_GREY, np.uint8)
    out[: size[1], : size[0]] = cv2.resize(image, size, interpolation=cv2.INTER_LINEAR)
    return out, ratio


def _nms(boxes: np.ndarray, scores: np.ndarray, iou: float) -> np.ndarray:
    order, keep = list(np.argsort(-scores)), []
    while order:
        best = order.pop(0)
        keep.append(best)
        if order:
            overlaps = box_iou(boxes[[best]], boxes[order])[0]
            order = [o for o, v in zip(order, overlaps) if v <= iou]
    return np.array(keep, int)


def decode_yolox(raw: np.ndarray, height: int, width: int, min_score: float) -> tuple[np.ndarray, np.ndarray]:
    """YOLOX's raw head [A, 5 + C] for an input of height x width -> person boxes [N, 4] (input pixels), scores."""
    grids, strides = [], []
    for stride in YOLOX_STRIDES:
        ys, xs = np.meshgrid(np.arange(height // stride), np.arange(width // stride), indexing="ij")
        grids.append(np.stack([xs.ravel(), ys.ravel()], 1))
        strides.append(np.full((xs.size, 1), stride))
    grid, stride = np.concatenate(grids), np.concatenate(strides)
    if len(grid) != len(raw):
        raise GlimpseError(f"YOLOX output has {len(raw)} anchors; an input of {height}x{width} with strides "
                           f"{YOLOX_STRIDES} has {len(grid)}")
    centre = (raw[:, :2] + grid) * stride
    size = np.exp(raw[:, 2:4]) * stride
    scores = raw[:, 4] * raw[:, 5 + PERSON_CLASS]
    keep = scores >= min_score
    boxes = np.concatenate([centre - size / 2, centre + size / 2], 1)[keep]
    scores = scores[keep]
    chosen = _nms(boxes, scores, YOLOX_NMS_IOU)
    return boxes[chosen], scores[chosen]


@dataclass
class OnnxDetector:
    """A user's person detector (see the module docstring)."""

    path: str
    kind: str  # rtmdet | yolox
    min_score: float
    threads: int = 1  # onnxruntime's intra-op threads

    def __post_init__(self) -> None:
        if self.kind not in ("rtmdet", "yolox"):
            raise GlimpseError(f"ingest.detector_onnx_kind must be rtmdet or yolox, found {self.kind!r}")
        self.session = _session(self.path, "detector", self.threads)
        self.height, self.width = _input_hw(self.session, "detector")

    def __call__(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """[H, W, 3] uint8 RGB -> person boxes [N, 4] (x0, y0, x1, y1, image pixels) and scores [N]."""
        boxed, ratio = letterbox(image[..., ::-1], self.height, self.width)  # BGR, as both were trained
        tensor = boxed.astype(np.float32)
        if self.kind == "rtmdet":
            tensor = (tensor - np.array(RTMDET_MEAN_BGR, np.float32)) / np.array(RTMDET_STD_BGR, np.float32)
        outputs = self.session.run(None, {self.session.get_inputs()[0].name: tensor.transpose(2, 0, 1)[None]})
        if len(outputs) >= 2 and outputs[0].shape[-1] == 5:  # mmdeploy end-to-end: dets, labels
            dets, labels = outputs[0][0], outputs[1][0]
            keep = (labels == PERSON_CLASS) & (dets[:, 4] >= self.min_score)
            boxes, scores = dets[keep, :4], dets[keep, 4]
        else:
            boxes, scores = decode_yolox(outputs[0][0], self.height, self.width, self.min_score)
        # letterbox pixel centres: image coordinate x maps to (x + 0.5) * ratio - 0.5
        return (boxes + 0.5) / ratio - 0.5, scores


def box_to_input(box: np.ndarray, height: int, width: int, padding: float) -> np.ndarray:
    """[2, 3] affine map from the model's input pixels to image pixels for a person's box: centred on the box,
    its size grown by ``padding`` and widened or heightened to the input's aspect ratio."""
    x0, y0, x1, y1 = box
    w, h = (x1 - x0) * padding, (y1 - y0) * padding
    if w * height > h * width:
        h = w * height / width
    else:
        w = h * width / height
    scale = np.array([w / width, h / height])
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
    offset = centre - scale * (np.array([width, height]) - 1) / 2
    return np.array([[scale[0], 0, offset[0]], [0, scale[1], offset[1]]])


def decode_simcc(simcc_x: np.ndarray, simcc_y: np.ndarray, width: int) -> tuple[np.ndarray, np.ndarray]:
    """simcc_x [K, W r], simcc_y [K, H r] -> ([K, 2] input pixels, [K] scores = the smaller of the two peaks)."""
    ratio = simcc_x.shape[1] / width
    points = np.stack([simcc_x.argmax(1), simcc_y.argmax(1)], 1) / ratio
    return points, np.minimum(simcc_x.max(1), simcc_y.max(1))


def decode_heatmaps(heatmaps: np.ndarray, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """[K, h, w] heatmaps -> ([K, 2] input pixels, [K] peak values), a quarter-cell step towards the higher
    neighbour."""
    count, rows, cols = heatmaps.shape
    flat = heatmaps.reshape(count, -1).argmax(1)
    y, x = np.divmod(flat, cols)
    points = np.stack([x, y], 1).astype(float)
    for k in range(count):
        if 0 < x[k] < cols - 1:
            points[k, 0] += HEATMAP_SUBPIXEL * np.sign(heatmaps[k, y[k], x[k] + 1] - heatmaps[k, y[k], x[k] - 1])
        if 0 < y[k] < rows - 1:
            points[k, 1] += HEATMAP_SUBPIXEL * np.sign(heatmaps[k, y[k] + 1, x[k]] - heatmaps[k, y[k] - 1, x[k]])
    stride = np.array([width / cols, height / rows])
    return (points + 0.5) * stride - 0.5, heatmaps.reshape(count, -1).max(1)


@dataclass
class OnnxPose:
    """A user's top-down pose model (see the module docstring)."""

    path: str
    box_padding: float
    threads: int = 1  # onnxruntime's intra-op threads

    def __post_init__(self) -> None:
        self.session = _session(self.path, "pose", self.threads)
        self.height, self.width = _input_hw(self.session, "pose")

    def __call__(self, image: np.ndarray, box: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The person in ``box`` (x0, y0, x1, y1) of ``image`` [H, W, 3] uint8 RGB -> COCO-17 keypoints [17, 2]
        (image pixels) and scores [17] (the model's, not calibrated probabilities)."""
        affine = box_to_input(box, self.height, self.width, self.box_padding)
        crop = cv2.warpAffine(image, affine, (self.width, self.height), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=0).astype(np.float32)
        tensor = (crop - np.array(IMAGENET_MEAN_RGB, np.float32)) / np.array(IMAGENET_STD_RGB, np.float32)
        outputs = self.session.run(None, {self.session.get_inputs()[0].name: tensor.transpose(2, 0, 1)[None]})
        if len(outputs) >= 2:
            points, scores = decode_simcc(outputs[0][0], outputs[1][0], self.width)
        else:
            points, scores = decode_heatmaps(outputs[0][0], self.height, self.width)
        if len(points) not in (COCO17, WHOLEBODY):
            raise GlimpseError(f"{self.path}: the pose model gives {len(points)} keypoints; Glimpse reads COCO-17 "
                               f"({COCO17}) or COCO-WholeBody ({WHOLEBODY})")
        image_points = points[:COCO17] @ affine[:, :2].T + affine[:, 2]
        return image_points, scores[:COCO17]
