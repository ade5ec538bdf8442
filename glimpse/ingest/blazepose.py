"""BlazePose (MediaPipe's pose models, Apache-2.0) run through LiteRT, without MediaPipe's own runtime.

Two models, taken out of the ``mediapipe`` wheel at set-up (``make models``; docs/ingest.md):

- ``pose_detection.tflite``: a single-shot detector on a 224x224 letterboxed image in [-1, 1]; 2,254 anchors,
  each with a box and four points (mid hip, a point whose distance from it is the body's radius, mid shoulder,
  the upper body's radius). It keys on faces, so it finds people who face the camera.
- ``pose_landmark_full.tflite``: on a 256x256 crop in [0, 1] of a person's region: 39 landmarks (33 body
  points, then the two alignment points of the next frame's region, then four more), a presence score, a
  256x256 segmentation of that person and metric root-relative 3D landmarks.

The decoding (anchors, boxes, non-maximum suppression, regions) is in pure numpy functions below; the two
classes only hold the interpreters.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.special import expit

from glimpse.errors import GlimpseError
from glimpse.ingest.crop import (
    Region,
    crop_image,
    crop_to_image,
    normalized_to_crop,
    region_from_alignment,
)

DETECTOR_FILE = "pose_detection.tflite"
LANDMARK_FILE = "pose_landmark_full.tflite"
DETECTOR_SIZE = 224
LANDMARK_SIZE = 256
# MediaPipe's SSD anchor options for the pose detector: strides of its five layers, two anchors per layer.
ANCHOR_STRIDES = (8, 16, 32, 32, 32)
ANCHORS_PER_LAYER = 2
DETECTOR_POINTS = 4  # mid hip, full-body radius point, mid shoulder, upper-body radius point
SCORE_CLIP = 100.0  # raw detector scores are clipped to +-100 before the sigmoid (MediaPipe)
REGION_GROW = 1.25  # MediaPipe grows the alignment square by 25% for the landmark crop
BODY_LANDMARKS = 33
LANDMARK_VALUES = 5  # x, y, z, visibility (logit), presence (logit)
ALIGNMENT_LANDMARKS = (33, 34)  # the landmark model's own mid hip and radius point: next frame's region
LANDMARK_COUNT = 39
HEATMAP_KERNEL = 7  # MediaPipe's heatmap refinement: a 7x7 window around each landmark ...
HEATMAP_MIN_CONFIDENCE = 0.5  # ... used when its peak probability reaches 0.5
# Mirror pairs (left, right) of the 33 body landmarks; the auxiliary ones (33-38) lie on the body's midline.
MIRROR_PAIRS = ((1, 4), (2, 5), (3, 6), (7, 8), (9, 10), (11, 12), (13, 14), (15, 16), (17, 18), (19, 20),
                (21, 22), (23, 24), (25, 26), (27, 28), (29, 30), (31, 32))
# The legs' mirror pairs: knees, ankles, heels, foot tips.
LEG_PAIRS = ((25, 26), (27, 28), (29, 30), (31, 32))
# BlazePose's 33 landmarks in COCO-17 order (nose, eyes, ears, shoulders, elbows, wrists, hips, knees, ankles).
COCO17_FROM_BLAZEPOSE = (0, 2, 5, 7, 8, 11, 12, 13, 14, 15, 16, 23, 24, 25, 26, 27, 28)


def ssd_anchor_centres() -> np.ndarray:
    """[2254, 2] anchor centres of the pose detector in [0, 1] (x, y), in the model's output order."""
    centres = []
    layer = 0
    while layer < len(ANCHOR_STRIDES):
        stride = ANCHOR_STRIDES[layer]
        same = 1
        while layer + same < len(ANCHOR_STRIDES) and ANCHOR_STRIDES[layer + same] == stride:
            same += 1
        cells = int(np.ceil(DETECTOR_SIZE / stride))
        ys, xs = np.meshgrid((np.arange(cells) + 0.5) / cells, (np.arange(cells) + 0.5) / cells, indexing="ij")
        grid = np.stack([xs.ravel(), ys.ravel()], axis=1)
        centres.append(np.repeat(grid, same * ANCHORS_PER_LAYER, axis=0))
        layer += same
    return np.concatenate(centres)


@dataclass(frozen=True)
class Detections:
    """Detections in one crop's normalised coordinates, or in image pixels after :func:`detections_to_image`."""

    boxes: np.ndarray  # [N, 4] x0, y0, x1, y1
    points: np.ndarray  # [N, 4, 2] the four alignment points
    scores: np.ndarray  # [N]

    def __len__(self) -> int:
        return len(self.scores)

    @staticmethod
    def concatenate(parts: list[Detections]) -> Detections:
        if not parts:
            return Detections(np.zeros((0, 4)), np.zeros((0, DETECTOR_POINTS, 2)), np.zeros(0))
        return Detections(*(np.concatenate([getattr(p, f) for p in parts]) for f in ("boxes", "points", "scores")))

    def regions(self) -> list[Region]:
        """The landmark model's region for each detection (mid hip centre, radius point)."""
        return [region_from_alignment(p[0], p[1], REGION_GROW) for p in self.points]


def decode_detections(raw_boxes: np.ndarray, raw_scores: np.ndarray, anchors: np.ndarray,
                      min_score: float) -> Detections:
    """raw_boxes [A, 12], raw_scores [A, 1] -> detections above ``min_score`` in normalised crop coordinates."""
    scores = expit(np.clip(raw_scores[:, 0], -SCORE_CLIP, SCORE_CLIP))
    keep = scores >= min_score
    values = raw_boxes[keep] / DETECTOR_SIZE
    centre = values[:, 0:2] + anchors[keep]
    half = values[:, 2:4] / 2
    points = values[:, 4:4 + 2 * DETECTOR_POINTS].reshape(-1, DETECTOR_POINTS, 2) + anchors[keep][:, None]
    return Detections(np.concatenate([centre - half, centre + half], axis=1), points, scores[keep])


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """[N, 4] x [M, 4] boxes (x0, y0, x1, y1) -> [N, M] intersection over union."""
    lo = np.maximum(a[:, None, :2], b[None, :, :2])
    hi = np.minimum(a[:, None, 2:], b[None, :, 2:])
    inter = np.prod(np.clip(hi - lo, 0, None), axis=2)
    area = lambda box: np.prod(np.clip(box[:, 2:] - box[:, :2], 0, None), axis=1)
    return inter / np.maximum(area(a)[:, None] + area(b)[None] - inter, 1e-9)


def weighted_nms(detections: Detections, iou_threshold: float) -> Detections:
    """MediaPipe's weighted non-maximum suppression: each kept detection is the score-weighted mean of the
    detections that overlap it by more than ``iou_threshold``."""
    order = np.argsort(-detections.scores)
    remaining = list(order)
    kept = []
    while remaining:
        best = remaining[0]
        overlap = box_iou(detections.boxes[[best]], detections.boxes[remaining])[0] > iou_threshold
        group = np.array(remaining)[overlap]
        weights = detections.scores[group][:, None]
        kept.append(Detections((detections.boxes[group] * weights).sum(0, keepdims=True) / weights.sum(),
                               (detections.points[group] * weights[:, :, None]).sum(0, keepdims=True) / weights.sum(),
                               detections.scores[[best]]))
        remaining = [r for r, o in zip(remaining, overlap) if not o]
    return Detections.concatenate(kept)


def detections_to_image(detections: Detections, region: Region) -> Detections:
    """Map detections from a crop's normalised coordinates to image pixels (an upright region only)."""
    to_image = lambda p: crop_to_image(region, normalized_to_crop(p, DETECTOR_SIZE), DETECTOR_SIZE)
    corners = to_image(detections.boxes.reshape(-1, 2)).reshape(-1, 4)
    points = to_image(detections.points.reshape(-1, 2)).reshape(-1, DETECTOR_POINTS, 2)
    return Detections(corners, points, detections.scores)


@dataclass(frozen=True)
class PoseLandmarks:
    """One person's landmarks in one region of one frame."""

    points: np.ndarray  # [33, 2] image pixels
    visibility: np.ndarray  # [33] probability that the point is visible (not hidden)
    presence: np.ndarray  # [33] probability that the point is inside the image
    world: np.ndarray  # [33, 3] metres, relative to the mid hip (x right, y down, z away from the camera)
    score: float  # probability that the region holds a person
    next_region: Region  # where this person will be looked for in the next frame
    segmentation: np.ndarray  # [256, 256] probability that a crop pixel shows this person
    region: Region  # the region the landmarks were found in
    run_points: np.ndarray | None = None  # [R, 33, 2] image pixels of each run ``points`` averages (crop, mirror)
    legs_disputed: float = 0.0  # share of the mirrored runs that named the legs the other way (legs_named_otherwise())

    def moved(self, shift: np.ndarray) -> PoseLandmarks:
        """These landmarks with their points moved by ``shift`` (2,) pixels (the rest as they are)."""
        return replace(self, points=self.points + shift)

    def coco17(self) -> tuple[np.ndarray, np.ndarray]:
        """([17, 2] pixels, [17] confidence = visibility x presence) in COCO-17 order."""
        index = list(COCO17_FROM_BLAZEPOSE)
        return self.points[index], self.visibility[index] * self.presence[index]

    def named_as(self, points: np.ndarray, max_ratio: float) -> PoseLandmarks:
        """These landmarks with each left/right pair named as ``points`` [33, 2] (image pixels) clearly name it
        otherwise: points, visibility, presence and 3D together, so that a joint keeps its own confidence and
        metric 3D point under its new name. Clearly: ``points``' pair lies less than ``max_ratio`` times as far
        from these landmarks' pair named the other way as from it as named (summed over the two points,
        :func:`sides_to_swap`); a side-on person's two eyes or shoulders, a pixel apart, keep their names."""
        pairs = sides_to_swap(self.points, points, max_ratio)
        if not pairs:
            return self
        return replace(self, points=swap_sides(self.points, pairs), visibility=swap_sides(self.visibility, pairs),
                       presence=swap_sides(self.presence, pairs), world=swap_sides(self.world, pairs))

    def coco17_relative3d(self) -> np.ndarray:
        """[17, 3] the COCO-17 landmarks in metres relative to the mid hip, in the image's axes (x right, y down,
        z away from the camera): the model's world landmarks, given in its crop's axes, turned by the crop's
        rotation about the viewing direction. (The model sees the person as a camera looking straight at
        them would; turning that onto a camera's own axes needs its intrinsics, which stage 02 has.)"""
        c, s = np.cos(self.region.angle), np.sin(self.region.angle)
        turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return self.world[list(COCO17_FROM_BLAZEPOSE)] @ turn.T


def landmark_image_points(raw: np.ndarray, region: Region) -> np.ndarray:
    """[39, 2] image pixels of every landmark in the landmark model's raw output [39 * 5] for ``region``'s crop
    (its x, y are pixels of the 256x256 crop, from its edges)."""
    return crop_to_image(region, raw.reshape(-1, LANDMARK_VALUES)[:, :2] - 0.5, LANDMARK_SIZE)


def decode_landmarks(raw: np.ndarray, score: float, world: np.ndarray, segmentation_logits: np.ndarray,
                     region: Region) -> PoseLandmarks:
    """The landmark model's outputs for a crop of ``region`` -> :class:`PoseLandmarks` in image pixels."""
    values = raw.reshape(-1, LANDMARK_VALUES)
    image_points = landmark_image_points(raw, region)
    centre, scale_point = image_points[list(ALIGNMENT_LANDMARKS)]
    return PoseLandmarks(
        points=image_points[:BODY_LANDMARKS], visibility=expit(values[:BODY_LANDMARKS, 3]),
        presence=expit(values[:BODY_LANDMARKS, 4]), world=world.reshape(-1, 3)[:BODY_LANDMARKS],
        score=float(score), next_region=region_from_alignment(centre, scale_point, REGION_GROW),
        segmentation=expit(segmentation_logits.reshape(LANDMARK_SIZE, LANDMARK_SIZE)), region=region)


def mirror_permutation(count: int = LANDMARK_COUNT) -> np.ndarray:
    """[count] index of each landmark's mirror image (left <-> right)."""
    order = np.arange(count)
    for left, right in MIRROR_PAIRS:
        order[left], order[right] = right, left
    return order


def refine_with_heatmap(raw: np.ndarray, heatmap_logits: np.ndarray) -> np.ndarray:
    """MediaPipe's landmark refinement: each landmark (raw [39 * 5], crop pixels from the crop's edges) moves to
    the probability-weighted mean of the heatmap ([64, 64, 39] logits) in a 7x7 window around it, when the window's
    peak is confident. Heatmap cells are taken at their centres."""
    values = raw.reshape(-1, LANDMARK_VALUES).copy()
    cells = heatmap_logits.shape[0]
    to_cells = cells / LANDMARK_SIZE
    half = HEATMAP_KERNEL // 2
    probability = expit(heatmap_logits)
    for j in range(min(len(values), probability.shape[2])):
        col, row = int(values[j, 0] * to_cells), int(values[j, 1] * to_cells)
        if not (0 <= col < cells and 0 <= row < cells):
            continue
        r0, r1, c0, c1 = max(0, row - half), min(cells, row + half + 1), max(0, col - half), min(cells, col + half + 1)
        window = probability[r0:r1, c0:c1, j]
        if window.max() < HEATMAP_MIN_CONFIDENCE:
            continue
        rows, cols = np.mgrid[r0:r1, c0:c1]
        values[j, 0] = np.sum((cols + 0.5) * window) / window.sum() / to_cells
        values[j, 1] = np.sum((rows + 0.5) * window) / window.sum() / to_cells
    return values.ravel()


def unmirror(raw: np.ndarray, world: np.ndarray, segmentation: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Outputs for a horizontally mirrored crop -> outputs for the crop itself (x flipped, left <-> right)."""
    order = mirror_permutation()
    values = raw.reshape(-1, LANDMARK_VALUES)[order].copy()
    values[:, 0] = LANDMARK_SIZE - values[:, 0]
    points = world.reshape(-1, 3)[order[: len(world.reshape(-1, 3))]].copy()
    points[:, 0] = -points[:, 0]
    return values.ravel(), points.ravel(), segmentation[:, ::-1]


def sides_to_swap(reference: np.ndarray, other: np.ndarray, max_ratio: float = 1.0) -> list[tuple[int, int]]:
    """The left/right landmark pairs of ``other`` that lie closer to ``reference``'s swapped than as named (less
    than ``max_ratio`` times as far, summed over the pair's two points); both [N, C] per-landmark rows (N >= 33)
    whose first two columns are x and y in one frame (raw values or image pixels). The model may call a side-on
    person's left what its mirrored run calls right, and a person facing the camera with their arms at rest may be
    taken, in one crop, for someone seen from behind: averaging across that would put a knee between the knees, or
    the ears together (see :func:`swap_sides`)."""
    pairs = []
    for left, right in MIRROR_PAIRS:
        a, b = reference[[left, right], :2], other[[left, right], :2]
        kept, swapped = np.linalg.norm(a - b, axis=1).sum(), np.linalg.norm(a - b[::-1], axis=1).sum()
        if swapped < max_ratio * kept:
            pairs.append((left, right))
    return pairs


def legs_named_otherwise(swaps: list[tuple[int, int]]) -> bool:
    """Whether a mirrored run named the legs the other way: at least half of :data:`LEG_PAIRS` among the pairs
    :func:`sides_to_swap` found it exchanged. A side-on walker's legs look alike, and the model then tends to
    give the front leg one side's name whichever it is; its mirrored run names it the other way. Where the two
    disagree, the labels are a guess (glimpse.ingest.sides.legs_to_exchange)."""
    return 2 * sum(pair in swaps for pair in LEG_PAIRS) >= len(LEG_PAIRS)


def swap_sides(values: np.ndarray, pairs: list[tuple[int, int]]) -> np.ndarray:
    """A copy of per-landmark ``values`` [N, C] with each (left, right) pair's rows exchanged."""
    out = values.copy()
    for left, right in pairs:
        out[[left, right]] = out[[right, left]]
    return out


def _interpreter(path: Path, threads: int):
    try:
        from ai_edge_litert.interpreter import Interpreter
    except ImportError as error:  # pragma: no cover - the package is a pinned dependency
        raise GlimpseError("the ingest needs the LiteRT runtime: pip install ai-edge-litert "
                           "(make venv installs it)") from error
    if not path.is_file():
        raise GlimpseError(f"{path}: BlazePose model file missing; run `make models` (it takes the models out of "
                           "the mediapipe wheel) or set ingest.blazepose_dir to a folder holding "
                           f"{DETECTOR_FILE} and {LANDMARK_FILE}")
    interpreter = Interpreter(model_path=str(path), num_threads=threads)
    interpreter.allocate_tensors()
    return interpreter


class _Model:
    def __init__(self, path: Path, threads: int):
        self.interpreter = _interpreter(path, threads)
        self.input_index = self.interpreter.get_input_details()[0]["index"]
        self.outputs = [d["index"] for d in self.interpreter.get_output_details()]

    def __call__(self, tensor: np.ndarray) -> list[np.ndarray]:
        self.interpreter.set_tensor(self.input_index, tensor[None].astype(np.float32))
        self.interpreter.invoke()
        return [self.interpreter.get_tensor(i)[0] for i in self.outputs]


class BlazePose:
    """The detector and the landmark model of one folder (see the module docstring)."""

    def __init__(self, folder: Path, threads: int = 1):
        self.detector = _Model(Path(folder) / DETECTOR_FILE, threads)
        self.landmarker = _Model(Path(folder) / LANDMARK_FILE, threads)
        self.anchors = ssd_anchor_centres()

    def detect(self, image: np.ndarray, region: Region, min_score: float) -> Detections:
        """Detections (image pixels, before suppression) in an upright square region of ``image`` [H, W, 3] uint8."""
        crop = crop_image(image, region, DETECTOR_SIZE).astype(np.float32) / 127.5 - 1.0
        raw_boxes, raw_scores = self.detector(crop)
        return detections_to_image(decode_detections(raw_boxes, raw_scores, self.anchors, min_score), region)

    def _landmark_outputs(self, crop: np.ndarray, refine: bool) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
        raw, score, segmentation, heatmap, world = self.landmarker(crop)
        if refine:
            raw = refine_with_heatmap(raw, heatmap)
        return raw, float(np.ravel(score)[0]), world, segmentation[..., 0]

    def _crop_runs(self, image: np.ndarray, region: Region, refine: bool, mirror: bool
                   ) -> tuple[list[tuple[np.ndarray, float, np.ndarray, np.ndarray]], list[bool]]:
        """The landmark model's (raw, score, world, segmentation) for ``region``'s crop and, with ``mirror``, for
        the mirrored crop, unmirrored and each left/right pair matched to the first run's (the model may call a
        side-on person's left what its mirrored run calls right); and, per mirrored run, whether it named the
        legs the other way (:func:`legs_named_otherwise`)."""
        crop = crop_image(image, region, LANDMARK_SIZE).astype(np.float32) / 255.0
        runs, disputes = [self._landmark_outputs(crop, refine)], []
        if mirror:
            raw_m, score_m, world_m, segmentation_m = self._landmark_outputs(crop[:, ::-1].copy(), refine)
            raw_m, world_m, segmentation_m = unmirror(raw_m, world_m, segmentation_m)
            swaps = sides_to_swap(runs[0][0].reshape(-1, LANDMARK_VALUES), raw_m.reshape(-1, LANDMARK_VALUES))
            disputes.append(legs_named_otherwise(swaps))
            raw_m = swap_sides(raw_m.reshape(-1, LANDMARK_VALUES), swaps).ravel()
            world_m = swap_sides(world_m.reshape(-1, 3), swaps).ravel()
            runs.append((raw_m, score_m, world_m, segmentation_m))
        return runs, disputes

    def landmarks(self, image: np.ndarray, region: Region, refine: bool = True, mirror_average: bool = False
                  ) -> PoseLandmarks:
        """The person in ``region`` of ``image`` [H, W, 3] uint8. refine: MediaPipe's heatmap refinement;
        mirror_average: also run on the mirrored crop and average the two (test-time augmentation)."""
        runs, disputes = self._crop_runs(image, region, refine, mirror_average)
        raw, world = sum(r[0] for r in runs) / len(runs), sum(r[2].ravel() for r in runs) / len(runs)
        segmentation, score = sum(r[3] for r in runs) / len(runs), sum(r[1] for r in runs) / len(runs)
        return replace(decode_landmarks(raw, score, world, segmentation, region),
                       run_points=np.stack([landmark_image_points(run[0], region)[:BODY_LANDMARKS] for run in runs]),
                       legs_disputed=float(np.mean(disputes)) if disputes else 0.0)

    def median_points(self, image: np.ndarray, landmarks: PoseLandmarks, shifts: tuple[float, ...], refine: bool,
                      mirror: bool) -> tuple[np.ndarray, float]:
        """([33, 2] image pixels, legs disputed): the per-coordinate median of ``landmarks``' runs and of the runs
        on its region moved sideways (along the crop's x axis) by each of ``shifts`` (fractions of the side), both
        ways, each with its mirror when ``mirror``; and the share of all those mirrored runs that named the legs
        the other way. ``image`` is the one the landmarks were found in. A gross error of a few crops (a knee put
        on the other leg) moves a median little, where it would move a mean. Each left/right pair is named as most
        runs name it: a moved crop may take a person facing the camera for one seen from behind, and a median
        across the two namings would put the ears together; so every run's pairs are named as ``landmarks``' own
        first run names them (:func:`sides_to_swap`) before the median, which then takes the name most runs gave
        (an even split keeps the first run's)."""
        region = landmarks.region
        sideways = region.side * np.array([np.cos(region.angle), np.sin(region.angle)])
        points = list(landmarks.run_points if landmarks.run_points is not None else [landmarks.points])
        mirrored = len(points) - 1
        disputed = landmarks.legs_disputed * mirrored
        swapped: list[tuple[int, int]] = []
        for shift in shifts:
            for sign in (1.0, -1.0):
                moved = Region(region.centre + sign * shift * sideways, region.side, region.angle)
                runs, disputes = self._crop_runs(image, moved, refine, mirror)
                for run in runs:
                    moved_points = landmark_image_points(run[0], moved)[:BODY_LANDMARKS]
                    swaps = sides_to_swap(points[0], moved_points)
                    swapped.extend(swaps)
                    points.append(swap_sides(moved_points, swaps))
                mirrored, disputed = mirrored + len(disputes), disputed + sum(disputes)
        median = np.median(np.stack(points), axis=0)
        majority = [pair for pair in sorted(set(swapped)) if 2 * swapped.count(pair) > len(points)]
        return swap_sides(median, majority), disputed / mirrored if mirrored else 0.0
