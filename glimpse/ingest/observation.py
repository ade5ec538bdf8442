"""What the tracker finds of one person in one frame (an :class:`Observation`), what it keeps of them over the
video (a :class:`Track`), and how two observations are compared: the same person, a piece of one, the
depth proxy, the skeleton that decides contested pixels. Pure functions of landmarks and masks; the tracker
(:mod:`glimpse.ingest.tracker`) runs them frame by frame."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from glimpse.ingest.appearance import appearance_distance, comparable
from glimpse.ingest.blazepose import PoseLandmarks
from glimpse.ingest.config import IngestConfig
from glimpse.ingest.crop import Region

# Bones (BlazePose landmark pairs) whose metric and pixel lengths give the depth proxy: shoulders-hips,
# hips-knees, knees-ankles, shoulders-elbows, both sides.
DEPTH_BONES = ((11, 23), (12, 24), (23, 25), (24, 26), (25, 27), (26, 28), (11, 13), (12, 14))
MID_HIPS = (23, 24)
MID_SHOULDERS = (11, 12)
TORSO_POLYGON = (11, 12, 24, 23)
# BlazePose landmark pairs drawn as the skeleton that decides contested mask pixels: head, arms, legs, feet.
SKELETON_LIMBS = ((0, 11), (0, 12), (7, 8), (11, 13), (13, 15), (12, 14), (14, 16), (15, 19), (16, 20), (23, 25),
                  (25, 27), (24, 26), (26, 28), (27, 29), (29, 31), (27, 31), (28, 30), (30, 32), (28, 32))
SAME_PERSON_CONFIDENCE = 0.5  # body points both observations are sure of are compared ...
SAME_PERSON_MIN_POINTS = 4  # ... when there are at least this many (else all 17)
PART_INSIDE = 0.9  # share of a small observation's landmark box inside a larger one's that makes it a piece of it


@dataclass
class Observation:
    landmarks: PoseLandmarks
    probability: np.ndarray  # [H, W] float32 probability that a pixel shows this person
    mask: np.ndarray  # [H, W] bool, probability above the threshold
    box: np.ndarray  # (4,) x0, y0, x1, y1 of the landmarks inside the image
    look: np.ndarray  # [2, D] appearance (glimpse.ingest.appearance)
    depth: float  # depth proxy, metres per pixel (larger = farther)
    keypoints: np.ndarray  # [17, 3] COCO-17 pixels and confidence (BlazePose's, or the ONNX pose model's)
    body: np.ndarray | None = None  # [H, W] bool, Tracker.body_pixels, computed once when first needed
    skeleton_distance: np.ndarray | None = None  # [H, W] float32 torso lengths, computed once when first needed
    image: np.ndarray | None = None  # [H, W, 3] the image the landmarks were found in (people painted over or not)
    legs_disputed: float = 0.0  # share of the model's mirrored runs that named the legs the other way
    relative3d: np.ndarray | None = None  # [17, 3] metric 3D points written with ``keypoints`` (None: landmarks')


@dataclass
class Track:
    index: int
    landmarks: PoseLandmarks  # the last observation's
    look: np.ndarray
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(2))
    missing: int = 0  # consecutive frames without an observation
    frames: list[int] = field(default_factory=list)
    keypoints: list[np.ndarray] = field(default_factory=list)  # [17, 3] per frame in ``frames``
    relative3d: list[np.ndarray] = field(default_factory=list)  # [17, 4] per frame: PoseLandmarks.coco17_relative3d, confidence
    boxes: list[np.ndarray] = field(default_factory=list)
    legs_disputed: list[float] = field(default_factory=list)  # per frame: Observation.legs_disputed
    reidentified: list[tuple[int, float]] = field(default_factory=list)  # (frame id, appearance distance)
    jumps: list[int] = field(default_factory=list)  # frame ids where the box jumped (suspected switches)
    looked_again: list[int] = field(default_factory=list)  # frame ids filled afterwards (:meth:`Tracker.look_again`)

    @property
    def region(self) -> Region:
        """Where the last landmarks say this person will be looked for next."""
        return self.landmarks.next_region

    def predicted_region(self) -> Region:
        return Region(self.region.centre + self.velocity * (1 + self.missing), self.region.side, self.region.angle)

    def predicted_landmarks(self) -> PoseLandmarks:
        """The last landmarks moved on by the track's velocity to this frame."""
        return self.landmarks.moved(self.velocity * (1 + self.missing))


def depth_proxy(landmarks: PoseLandmarks) -> float:
    """Metres per pixel along the body's bones (visible ones weigh more): proportional to the distance."""
    metric = np.array([np.linalg.norm(landmarks.world[a] - landmarks.world[b]) for a, b in DEPTH_BONES])
    pixels = np.array([np.linalg.norm(landmarks.points[a] - landmarks.points[b]) for a, b in DEPTH_BONES])
    weight = np.array([landmarks.visibility[a] * landmarks.visibility[b] for a, b in DEPTH_BONES]) + 1e-3
    return float(np.sum(weight * metric) / max(np.sum(weight * pixels), 1e-6))


def torso_length(landmarks: PoseLandmarks) -> float:
    """Pixels from the mid hip to the mid shoulder: the person's scale in the image."""
    return float(max(np.linalg.norm(landmarks.points[list(MID_SHOULDERS)].mean(0)
                                    - landmarks.points[list(MID_HIPS)].mean(0)), 1.0))


def same_person(a: PoseLandmarks, b: PoseLandmarks, config: IngestConfig) -> bool:
    """Whether two sets of landmarks describe one person: their body points (COCO-17, both confident) lie within
    ``track_same_person`` torso lengths of each other on average, or at least ``track_shared_points`` of them
    each within ``track_shared_point_distance`` (a second, wrong fit of one person: the same head on other
    arms and legs, or the same legs under another head; two people do not share several joints). Masks cannot
    tell: the landmark model segments every person in its crop, so two people who overlap have overlapping
    masks."""
    points_a, confidence_a = a.coco17()
    points_b, confidence_b = b.coco17()
    return same_body_points(np.concatenate([points_a, confidence_a[:, None]], 1),
                            np.concatenate([points_b, confidence_b[:, None]], 1),
                            (torso_length(a) + torso_length(b)) / 2, config)


def same_body_points(a: np.ndarray, b: np.ndarray, scale: float, config: IngestConfig) -> bool:
    """:func:`same_person` on two people's COCO-17 keypoints ``a``, ``b`` [17, 3] (pixels, confidence), ``scale``
    pixels per torso length."""
    both = (a[:, 2] > SAME_PERSON_CONFIDENCE) & (b[:, 2] > SAME_PERSON_CONFIDENCE)
    confident_pairs = both.copy()
    if both.sum() < SAME_PERSON_MIN_POINTS:
        both = np.ones_like(both)
    distance = np.linalg.norm(a[:, :2] - b[:, :2], axis=1)
    shared = np.count_nonzero(confident_pairs & (distance < config.track_shared_point_distance * scale))
    return bool(distance[both].mean() < config.track_same_person * scale or shared >= config.track_shared_points)


def looks_like(track: Track, observation: Observation, max_distance: float) -> bool:
    """Whether what was found looks like the track's person: appearance distance at most ``max_distance``, or no
    half of the body that both appearances have (then the appearance says nothing either way)."""
    return (not comparable(track.look, observation.look)
            or appearance_distance(track.look, observation.look) <= max_distance)


def part_of(small: Observation, large: Observation, max_scale: float) -> bool:
    """Whether ``small`` is a piece of ``large``'s person taken for a whole person (a face the detector found,
    fitted as a tiny body): at most ``max_scale`` of its torso length, its landmark box inside the other's."""
    if torso_length(small.landmarks) > max_scale * torso_length(large.landmarks):
        return False
    lo, hi = np.maximum(small.box[:2], large.box[:2]), np.minimum(small.box[2:], large.box[2:])
    inside = np.prod(np.clip(hi - lo, 0, None))
    area = np.prod(np.clip(small.box[2:] - small.box[:2], 1e-6, None))
    return bool(inside / area > PART_INSIDE)


def one_person(a: Observation, b: Observation, config: IngestConfig) -> bool:
    """Whether two observations show one person: the same body, or one a piece of the other."""
    return (part_of(a, b, config.track_part_scale) or part_of(b, a, config.track_part_scale)
            or same_person(a.landmarks, b.landmarks, config))


def skeleton_distance(landmarks: PoseLandmarks, shape: tuple[int, int]) -> np.ndarray:
    """[H, W] float32: each pixel's distance to the person's skeleton (limbs as lines, the torso filled), in torso
    lengths."""
    height, width = shape
    skeleton = np.full((height, width), 255, np.uint8)
    points = np.round(landmarks.points).astype(np.int32)
    cv2.fillConvexPoly(skeleton, points[list(TORSO_POLYGON)], 0)
    for a, b in SKELETON_LIMBS:
        cv2.line(skeleton, tuple(points[a]), tuple(points[b]), 0, 1)
    distance = cv2.distanceTransform(skeleton, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return distance / torso_length(landmarks)


def observed_skeleton_distance(observation: Observation) -> np.ndarray:
    """:func:`skeleton_distance` of an observation's landmarks over its mask's shape, computed once and kept."""
    if observation.skeleton_distance is None:
        observation.skeleton_distance = skeleton_distance(observation.landmarks, observation.mask.shape)
    return observation.skeleton_distance
