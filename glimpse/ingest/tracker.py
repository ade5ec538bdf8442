"""Finding and following every person through a video, one id from entry to exit.

Per frame (BlazePose's own scheme, extended to several people):

1. **Follow.** Every track looks for its person in the region its last landmarks predicted (moved by the
   track's velocity); the landmark model's presence score says whether the person is still there.
2. **Find.** Candidate regions come from the pose detector on the whole frame and on overlapping tiles (small
   people), and, for a fixed camera, from pixels that differ from the background plate and no followed person
   explains (people seen from behind, whom the face-keyed detector misses). A candidate that no followed
   person covers is looked at by the landmark model.
3. **Resolve.** Two observations of the same pixels (a track that slid onto another person at a crossing, or a
   candidate that is a followed person) keep the one whose appearance matches its track best; the other
   track is hidden this frame.
4. **Re-identify.** New observations are matched to hidden and lost tracks by appearance (Hungarian method);
   what stays unmatched starts a new track.

Masks are depth-ordered: each frame's people are ranked by a depth proxy (metric bone lengths from the
landmark model's 3D output over their lengths in pixels) and the nearest takes the pixels it claims first.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from glimpse.ingest.appearance import appearance, appearance_distance, blend
from glimpse.ingest.blazepose import (
    BlazePose,
    Detections,
    PoseLandmarks,
    box_iou,
    weighted_nms,
)
from glimpse.ingest.config import IngestConfig
from glimpse.ingest.crop import Region, paste_to_image, region_around_box

# Bones (BlazePose landmark pairs) whose metric and pixel lengths give the depth proxy: shoulders-hips,
# hips-knees, knees-ankles, shoulders-elbows, both sides.
DEPTH_BONES = ((11, 23), (12, 24), (23, 25), (24, 26), (25, 27), (26, 28), (11, 13), (12, 14))
MID_HIPS = (23, 24)
VELOCITY_SMOOTHING = 0.5  # weight of the newest displacement in a track's velocity
UNMATCHED = 1e6  # assignment cost of a pair that must not match


@dataclass
class Observation:
    landmarks: PoseLandmarks
    probability: np.ndarray  # [H, W] float32 probability that a pixel shows this person
    mask: np.ndarray  # [H, W] bool, probability above the threshold
    box: np.ndarray  # (4,) x0, y0, x1, y1 of the mask (or of the landmarks when the mask is empty)
    look: np.ndarray  # [2, D] appearance (glimpse.ingest.appearance)
    depth: float  # depth proxy, metres per pixel (larger = farther)


@dataclass
class Track:
    index: int
    region: Region
    look: np.ndarray
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(2))
    missing: int = 0  # consecutive frames without an observation
    frames: list[int] = field(default_factory=list)
    keypoints: list[np.ndarray] = field(default_factory=list)  # [17, 3] per frame in ``frames``
    boxes: list[np.ndarray] = field(default_factory=list)
    reidentified: list[tuple[int, float]] = field(default_factory=list)  # (frame id, appearance distance)
    jumps: list[int] = field(default_factory=list)  # frame ids where the box jumped (suspected switches)

    def predicted_region(self) -> Region:
        return Region(self.region.centre + self.velocity * (1 + self.missing), self.region.side, self.region.angle)


def depth_proxy(landmarks: PoseLandmarks) -> float:
    """Metres per pixel along the body's bones (visible ones weigh more): proportional to the distance."""
    metric = np.array([np.linalg.norm(landmarks.world[a] - landmarks.world[b]) for a, b in DEPTH_BONES])
    pixels = np.array([np.linalg.norm(landmarks.points[a] - landmarks.points[b]) for a, b in DEPTH_BONES])
    weight = np.array([landmarks.visibility[a] * landmarks.visibility[b] for a, b in DEPTH_BONES]) + 1e-3
    return float(np.sum(weight * metric) / max(np.sum(weight * pixels), 1e-6))


def mask_iou(a: Observation, b: Observation) -> float:
    """Intersection over union of two observations' masks (computed on their boxes' union)."""
    x0, y0 = np.floor(np.minimum(a.box[:2], b.box[:2])).astype(int)
    x1, y1 = np.ceil(np.maximum(a.box[2:], b.box[2:])).astype(int) + 1
    x0, y0 = max(x0, 0), max(y0, 0)
    ma, mb = a.mask[y0:y1, x0:x1], b.mask[y0:y1, x0:x1]
    union = np.logical_or(ma, mb).sum()
    return float(np.logical_and(ma, mb).sum() / union) if union else 0.0


def foreground_regions(image: np.ndarray, plate: np.ndarray, explained: np.ndarray, config: IngestConfig
                       ) -> list[Region]:
    """Regions around connected pixels that differ from the plate and no observed person explains."""
    difference = np.abs(image.astype(np.int16) - plate.astype(np.int16)).max(axis=2) > config.foreground_threshold
    difference &= ~explained
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
    difference = cv2.morphologyEx(difference.astype(np.uint8), cv2.MORPH_OPEN, kernel)
    _, _, stats, _ = cv2.connectedComponentsWithStats(difference)
    min_area = config.foreground_min_area * image.shape[0] * image.shape[1]
    regions = []
    for x, y, w, h, area in stats[1:]:
        if area >= min_area:
            regions.append(region_around_box(np.array([x, y, x + w - 1, y + h - 1], float), config.foreground_region_grow))
    return regions


def detector_regions(model: BlazePose, image: np.ndarray, config: IngestConfig) -> list[Region]:
    """Landmark regions of the detector's people on the whole frame and on ``detect_tiles``^2 overlapping tiles."""
    height, width = image.shape[:2]
    crops = [Region(np.array([(width - 1) / 2, (height - 1) / 2]), float(max(width, height)), 0.0)]
    tiles = config.detect_tiles
    if tiles > 1:
        side = max(width, height) / tiles * (1 + config.detect_tile_overlap)
        for cy in np.linspace(side / 2, height - side / 2, tiles) if height > side else [(height - 1) / 2]:
            for cx in np.linspace(side / 2, width - side / 2, tiles) if width > side else [(width - 1) / 2]:
                crops.append(Region(np.array([cx, cy]), side, 0.0))
    found = [model.detect(image, crop, config.detect_min_score) for crop in crops]
    return weighted_nms(Detections.concatenate(found), config.detect_nms_iou).regions()


class Tracker:
    """Runs the per-frame steps of the module docstring; ``tracks`` holds every track ever started."""

    def __init__(self, model: BlazePose, config: IngestConfig, plate: np.ndarray | None):
        self.model, self.config, self.plate = model, config, plate
        self.tracks: list[Track] = []

    # ------------------------------------------------------------------ one person in one region
    def observe(self, image: np.ndarray, region: Region) -> Observation | None:
        """Landmarks in ``region`` (re-centred ``landmark_refine_steps`` times), or None when nobody is there."""
        config = self.config
        for _ in range(config.landmark_refine_steps):
            found = self.model.landmarks(image, region, refine=False)
            if found.score < config.landmark_min_presence:
                return None
            region = found.next_region
        found = self.model.landmarks(image, region, config.landmark_refine_heatmap, config.landmark_flip_average)
        if found.score < config.landmark_min_presence:
            return None
        height, width = image.shape[:2]
        probability = paste_to_image(found.segmentation, found.region, width, height)
        mask = probability > config.mask_threshold
        if mask.any():
            ys, xs = np.nonzero(mask)
            box = np.array([xs.min(), ys.min(), xs.max(), ys.max()], float)
        else:
            box = np.concatenate([found.points.min(0), found.points.max(0)])
        split = float(found.points[list(MID_HIPS), 1].mean())
        return Observation(found, probability, mask, box, appearance(image, mask, split, config.appearance_bins),
                           depth_proxy(found))

    # ------------------------------------------------------------------ one frame
    def step(self, frame_id: int, image: np.ndarray) -> list[tuple[Track, Observation]]:
        """Track, find and resolve the people of one frame; returns each observed track with its observation."""
        config = self.config
        live = [t for t in self.tracks if t.missing <= config.track_max_missing_frames]
        followed: dict[int, Observation] = {}
        for track in live:
            observation = self.observe(image, track.predicted_region())
            if observation is not None:
                followed[track.index] = observation
        self._resolve_duplicates(followed)
        fresh = self._find_new(image, list(followed.values()))
        assigned = self._assign(fresh, [t for t in live if t.index not in followed], frame_id)
        for track, observation in assigned:
            followed[track.index] = observation
        result = []
        for track in self.tracks:
            observation = followed.get(track.index)
            if observation is None:
                track.missing += 1
                continue
            self._update(track, observation, frame_id)
            result.append((track, observation))
        return result

    def _resolve_duplicates(self, followed: dict[int, Observation]) -> None:
        tracks = {t.index: t for t in self.tracks}
        indices = sorted(followed)
        for i, a in enumerate(indices):
            for b in indices[i + 1:]:
                if a not in followed or b not in followed:
                    continue
                if mask_iou(followed[a], followed[b]) <= self.config.track_duplicate_iou:
                    continue
                cost_a = appearance_distance(tracks[a].look, followed[a].look)
                cost_b = appearance_distance(tracks[b].look, followed[b].look)
                del followed[b if cost_a <= cost_b else a]

    def _find_new(self, image: np.ndarray, observed: list[Observation]) -> list[Observation]:
        candidates = detector_regions(self.model, image, self.config)
        if self.plate is not None:
            explained = np.zeros(image.shape[:2], bool)
            for observation in observed:
                explained |= observation.probability > self.config.mask_threshold / 2
            candidates += foreground_regions(image, self.plate, explained, self.config)
        fresh: list[Observation] = []
        for region in candidates:
            boxes = np.array([o.box for o in observed + fresh]).reshape(-1, 4)
            if len(boxes) and box_iou(region.box()[None], boxes).max() > self.config.track_duplicate_iou:
                continue
            observation = self.observe(image, region)
            if observation is None:
                continue
            if any(mask_iou(observation, other) > self.config.track_duplicate_iou for other in observed + fresh):
                continue
            fresh.append(observation)
        return fresh

    def _assign(self, fresh: list[Observation], waiting: list[Track], frame_id: int) -> list[tuple[Track, Observation]]:
        """Match new observations to tracks not seen this frame (Hungarian, on appearance); start the rest."""
        pairs: list[tuple[Track, Observation]] = []
        matched: set[int] = set()
        if fresh and waiting:
            cost = np.array([[appearance_distance(t.look, o.look) for t in waiting] for o in fresh])
            cost = np.where(cost <= self.config.track_reid_max_distance, cost, UNMATCHED)
            rows, cols = linear_sum_assignment(cost)
            for r, c in zip(rows, cols):
                if cost[r, c] < UNMATCHED:
                    track = waiting[c]
                    if track.missing > 0:
                        track.reidentified.append((frame_id, float(cost[r, c])))
                    pairs.append((track, fresh[r]))
                    matched.add(r)
        for r, observation in enumerate(fresh):
            if r in matched:
                continue
            track = Track(len(self.tracks), observation.landmarks.next_region, observation.look)
            self.tracks.append(track)
            pairs.append((track, observation))
        return pairs

    def _update(self, track: Track, observation: Observation, frame_id: int) -> None:
        config = self.config
        landmarks = observation.landmarks
        if track.frames:
            step = landmarks.next_region.centre - track.region.centre
            track.velocity = (1 - VELOCITY_SMOOTHING) * track.velocity + VELOCITY_SMOOTHING * step / (1 + track.missing)
            previous = track.boxes[-1]
            jump = np.linalg.norm((observation.box[:2] + observation.box[2:]) / 2 - (previous[:2] + previous[2:]) / 2)
            if jump > config.track_switch_distance * max(previous[3] - previous[1], 1.0) * (1 + track.missing):
                track.jumps.append(frame_id)
        track.region = landmarks.next_region
        track.missing = 0
        track.look = blend(track.look, observation.look, config.appearance_update)
        points, confidence = landmarks.coco17()
        height, width = observation.mask.shape
        inside = (points[:, 0] >= -0.5) & (points[:, 0] <= width - 0.5) & (points[:, 1] >= -0.5) & (points[:, 1] <= height - 0.5)
        confidence = np.where(inside, confidence, 0.0)
        confidence = np.where(confidence >= config.keypoint_min_confidence, confidence, 0.0)
        track.frames.append(frame_id)
        track.keypoints.append(np.concatenate([np.where(confidence[:, None] > 0, points, 0.0), confidence[:, None]], 1))
        track.boxes.append(observation.box)


def depth_ordered_labels(observations: list[tuple[Track, Observation]], shape: tuple[int, int],
                         threshold: float) -> np.ndarray:
    """[H, W] uint16: 0 for nobody, else 1 + the index of the track that owns the pixel, nearest first."""
    labels = np.zeros(shape, np.uint16)
    for track, observation in sorted(observations, key=lambda pair: pair[1].depth):
        labels[(observation.probability > threshold) & (labels == 0)] = track.index + 1
    return labels
