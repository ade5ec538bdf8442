"""Finding and following every person through a video, one id from entry to exit.

Per frame (BlazePose's own scheme, extended to several people):

1. **Follow.** Every track looks for its person in the region its last landmarks predicted (moved by the
   track's velocity); the landmark model's presence score says whether the person is still there, and
   whoever is there must look like the track (``track_follow_max_distance``), else the region slid onto
   someone else. Whom a track that had lost its person finds so goes to a track that found nobody, whose region
   lies over them too, when they look like it clearly better (``track_reclaim_margin``); a find that looks clearly
   more like another live track whose region lies over it is dropped, and the track looks behind (step 2).
2. **Resolve.** Two tracks that found one person (their body points coincide: a region that slid onto
   someone else at a crossing) keep the one whose appearance matches its track best; the other *looks
   behind*: its region again with the people already found painted over by the background plate (where the
   plate does not show the background, by their surroundings' colour), which leaves whoever they hide. A track
   that found nobody while its region overlaps someone found looks behind too. Only the found people's pixels
   nearer to their own skeleton than to where the hidden person's skeleton is expected (the last one moved by
   the velocity) are painted, and what the track finds must look like it (as when following; closer still for
   a track that was already missing) and must not lie mostly on the bodies of the people found.
3. **Find.** Candidate regions come from the pose detector (BlazePose's on the whole frame and on overlapping
   tiles for small people, or the user's ONNX detector), and, for a fixed camera, from pixels that differ
   from the background plate and no found person's body explains (people seen from behind, whom the
   face-keyed detector misses; :mod:`glimpse.ingest.foreground`: blobs of people side by side are also cut
   into person-wide windows, looked at with the rest painted over by the plate, and what remains is looked
   at again after a round that found someone; whoever is found there must in part differ from the plate). A
   candidate no found person covers is looked at by the landmark model, with the people found painted over;
   what it finds is kept unless it is someone found already or lies mostly on their bodies.
4. **Reclaim and re-identify.** A new observation that overlaps what a track followed and looks like that track
   clearly better is the track's person (the followed fit had slid half onto someone else). The others are
   matched to hidden and lost tracks by appearance (Hungarian method); what stays unmatched starts a new track.
   (The rules that give a person from one track to another are in :mod:`glimpse.ingest.claims`.)

Masks are depth-ordered (:mod:`glimpse.ingest.depth_order`): people are ranked by where their feet are in the
image (lower = nearer, for people on one floor), or by a depth proxy (metric bone lengths from the landmark model's
3D output over their lengths in pixels); a pixel several segmentations claim goes to the nearest person whose
skeleton passes close to it, else to the closest skeleton.
"""

from __future__ import annotations

import bisect
from typing import Literal

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from glimpse.ingest.appearance import appearance, appearance_distance, blend
from glimpse.ingest.blazepose import COCO17_FROM_BLAZEPOSE, BlazePose, PoseLandmarks, box_iou
from glimpse.ingest.claims import drop_lookalikes, reclaim, return_refound
from glimpse.ingest.config import IngestConfig
from glimpse.ingest.crop import Region, box_centre, outside_image, paste_to_image
from glimpse.ingest.depth_order import nearness_rank
from glimpse.ingest.detection import detector_regions
from glimpse.ingest.foreground import beside_fill, differs_from_plate, foreground_candidates, surroundings_fill
from glimpse.ingest.observation import (
    MID_HIPS,
    Observation,
    Track,
    depth_proxy,
    looks_like,
    observed_skeleton_distance,
    one_person,
    part_of,
    same_body_points,
    same_person,
    skeleton_distance,
    torso_length,
)
from glimpse.ingest.occlusion import NOBODY, joints_on_others
from glimpse.ingest.onnx_models import OnnxDetector, OnnxPose

VELOCITY_SMOOTHING = 0.5  # weight of the newest displacement in a track's velocity
UNMATCHED = 1e6  # assignment cost of a pair that must not match
SAME_REGION_IOU = 0.9  # a foreground region this close (IoU) to one looked at in an earlier round is not looked again
STILL_WIDTH = 0.02  # fraction of the frame's height: where the plate shows a found person in a region at least
# this wide, they stood still (specks where their colour matches the background's are painted by the plate)


def recorded_keypoints(keypoints: np.ndarray, shape: tuple[int, int], min_confidence: float) -> np.ndarray:
    """[17, 3] keypoints (pixels, confidence) of an image of ``shape`` (H, W) -> the same with those outside the
    image or below ``min_confidence`` missing (confidence 0, position 0)."""
    points, confidence = keypoints[:, :2], keypoints[:, 2]
    confidence = np.where(outside_image(points, shape), 0.0, confidence)
    confidence = np.where(confidence >= min_confidence, confidence, 0.0)
    return np.concatenate([np.where(confidence[:, None] > 0, points, 0.0), confidence[:, None]], 1)


def recorded_relative3d(observation: Observation, confidence: np.ndarray) -> np.ndarray:
    """[17, 4]: the observation's metric 3D points written beside its keypoints (those the written keypoints' runs
    named, else its landmarks'), zero where ``confidence`` [17] (the recorded keypoints') is 0, and that confidence."""
    relative = (observation.relative3d if observation.relative3d is not None
                else observation.landmarks.coco17_relative3d())
    return np.concatenate([np.where(confidence[:, None] > 0, relative, 0.0), confidence[:, None]], 1)


class Tracker:
    """Runs the per-frame steps of the module docstring; ``tracks`` holds every track ever started."""

    def __init__(self, model: BlazePose, config: IngestConfig, plate: np.ndarray | None,
                 detector: OnnxDetector | None = None, pose: OnnxPose | None = None):
        """detector: finds new people instead of BlazePose's detector; pose: gives the keypoints instead of
        BlazePose's landmarks (BlazePose still follows and segments everyone)."""
        self.model, self.config, self.plate = model, config, plate
        self.detector, self.pose = detector, pose
        self.tracks: list[Track] = []

    # ------------------------------------------------------------------ one person in one region
    def observe(self, image: np.ndarray, region: Region, original: np.ndarray | None = None,
                covered: np.ndarray | None = None) -> Observation | None:
        """Landmarks in ``region`` (re-centred ``landmark_refine_steps`` times), or None when nobody is there.
        When ``image`` has pixels ``covered`` [H, W] bool painted over (:meth:`_painted_over`), ``original`` is
        the frame before; the appearance is taken from it, over the person's mask less the covered pixels (the
        model's segmentation often goes on over them, where the frame shows someone else)."""
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
        inside = found.points[found.presence > config.landmark_min_presence]
        inside = inside if len(inside) else found.points
        box = np.concatenate([inside.min(0), inside.max(0)])
        split = float(found.points[list(MID_HIPS), 1].mean())
        points, confidence = found.coco17()
        own = mask if covered is None else mask & ~covered
        look = appearance(image if original is None else original, own, split, config.appearance_bins)
        return Observation(found, probability, mask, box, look,
                           depth_proxy(found), np.concatenate([points, confidence[:, None]], 1), image=image,
                           legs_disputed=found.legs_disputed)

    # ------------------------------------------------------------------ one frame
    def step(self, frame_id: int, image: np.ndarray) -> list[tuple[Track, Observation]]:
        """Track, find and resolve the people of one frame; returns each observed track with its observation."""
        config = self.config
        live = [t for t in self.tracks if t.missing <= config.track_max_missing_frames]
        followed: dict[int, Observation] = {}
        for track in live:
            observation = self.observe(image, track.predicted_region())
            if observation is None:
                continue
            if looks_like(track, observation, config.track_follow_max_distance):
                followed[track.index] = observation
        return_refound(followed, live, config.track_reclaim_margin)
        if config.track_drop_lookalikes:
            drop_lookalikes(followed, live, config.track_reclaim_margin)
        behind = set(self._resolve_duplicates(followed)) | self._hidden_by_others(live, followed)
        self._look_behind_all(image, followed, [t for t in live if t.index in behind])
        fresh = self._find_new(image, list(followed.values()))
        reclaim(fresh, followed, self.tracks, config.track_reclaim_margin)
        assigned = self._assign(fresh, [t for t in live if t.index not in followed], frame_id)
        for track, observation in assigned:
            followed[track.index] = observation
        result = []
        nearness = self._nearness(followed)
        for track in self.tracks:
            observation = followed.get(track.index)
            if observation is None:
                track.missing += 1
                continue
            others = [o for index, o in followed.items() if index != track.index]
            in_front = [nearness[track.index] < nearness[index] for index in followed if index != track.index]
            self.written_keypoints(image, observation, others, in_front)
            self._update(track, observation, frame_id, self._clear_of(observation, others))
            result.append((track, observation))
        return result

    def _nearness(self, followed: dict[int, Observation]) -> dict[int, float]:
        """Track index -> :func:`nearness_rank` of its person found this frame (smaller = nearer the camera; the cue
        of the depth-ordered masks, over the track's frames before this one)."""
        tracks = {t.index: t for t in self.tracks}
        config = self.config
        return {index: nearness_rank(tracks[index], observation, config.mask_depth_cue, config.mask_depth_frames)
                for index, observation in followed.items()}

    def written_keypoints(self, image: np.ndarray, observation: Observation,
                          others: list[Observation] | None = None, in_front: list[bool] | None = None) -> None:
        """Set the keypoints the scene gets: the user's pose model's, or the median of BlazePose's runs over
        shifted crops (``keypoint_crop_shifts``), else the observation's own. With ``keypoints_paint_others``,
        BlazePose's runs see the ``others`` found in the frame painted over (:meth:`_without_others`; ``in_front``:
        per other, whether this person is nearer): at a crossing the model takes the other person's legs for this
        one's."""
        config = self.config
        if self.pose is not None:
            points, scores = self.pose(image, observation.box)
            observation.keypoints = np.concatenate([points, np.clip(scores, 0.0, 1.0)[:, None]], 1)
            observation.legs_disputed = 0.0  # BlazePose's runs say nothing about another model's names
            return
        source, landmarks = observation.image, observation.landmarks
        if config.keypoints_paint_others and others:
            source, landmarks = self._without_others(image, observation, others, in_front or [False] * len(others))
        if config.keypoint_crop_shifts:
            points, observation.legs_disputed = self.model.median_points(
                source, landmarks, tuple(config.keypoint_crop_shifts), config.landmark_refine_heatmap,
                config.landmark_flip_average)
        elif landmarks is not observation.landmarks:
            points, observation.legs_disputed = landmarks.points, landmarks.legs_disputed
        else:
            return
        # the confidences and 3D points written beside these points are the observation's own, named as they are
        # (its landmarks, which tracking goes on with, keep one run's names)
        named = observation.landmarks.named_as(points, config.keypoint_rename_ratio)
        observation.keypoints = np.concatenate([points[list(COCO17_FROM_BLAZEPOSE)], named.coco17()[1][:, None]], 1)
        observation.relative3d = named.coco17_relative3d()

    def _without_others(self, frame: np.ndarray, observation: Observation, others: list[Observation],
                        in_front: list[bool]) -> tuple[np.ndarray, PoseLandmarks]:
        """(image, landmarks): the observation's image (the frame it was found in, with whoever was painted over to
        find it painted) with the ``others``' body pixels nearer to their own skeleton than to the observation's
        painted over (:meth:`_painted_over`, told who stood still by ``frame``, that frame unpainted: pixels the
        image has painted with the plate already show the plate, and are nobody standing still; who did is painted
        as ``keypoints_paint_still_with`` says), less the observation's own body pixels where it is ``in_front`` of
        that other person (per other: their body does not hide this one's), and the landmark model's run on it in
        the observation's region; the observation's own image and landmarks when no such pixel lies in the region
        or the model finds nobody there once they are painted."""
        own_distance = observed_skeleton_distance(observation)
        own_body = self.body_pixels(observation)
        theirs = np.zeros(observation.mask.shape, bool)
        for other, spare_own in zip(others, in_front):
            pixels = self.body_pixels(other) & (observed_skeleton_distance(other) <= own_distance)
            theirs |= pixels & ~own_body if spare_own else pixels
        x0, y0, x1, y1 = np.round(observation.landmarks.region.box()).astype(int)
        height, width = theirs.shape
        if not theirs[max(y0, 0):min(y1, height), max(x0, 0):min(x1, width)].any():
            return observation.image, observation.landmarks
        painted = self._painted_over(observation.image, theirs, theirs | own_body, frame,
                                     self.config.keypoints_paint_still_with)
        landmarks = self.model.landmarks(painted, observation.landmarks.region, self.config.landmark_refine_heatmap,
                                         self.config.landmark_flip_average)
        if landmarks.score < self.config.landmark_min_presence:
            return observation.image, observation.landmarks
        return painted, landmarks

    def look_again(self, image: np.ndarray, region: Region, others: np.ndarray, track: Track, frame_id: int,
                   others_keypoints: list[np.ndarray] | None = None) -> Observation | None:
        """A frame the track missed, looked at again afterwards (glimpse.ingest.backfill): its person in ``region``
        with the people found there (``others`` [H, W] bool, their labels) painted over (:meth:`_painted_over`).
        Kept, and recorded in the track at ``frame_id`` (its state, which describes a later frame, unchanged),
        only when it lies mostly off the others (``track_behind_max_overlap``), looks like the track as a
        re-identified person must (``track_reid_max_distance``) and, given ``others_keypoints`` ([17, 3] each,
        those recorded for the people found in that frame), is none of them (:func:`same_body_points`); its
        keypoints are recorded as not seen when it lies on the others more than
        ``track_backfill_keypoints_max_overlap`` (the model's guess at someone mostly hidden)."""
        config = self.config
        observation = self.observe(self._painted_over(image, others, others), region, image, others)
        if observation is None:
            return None
        scale = torso_length(observation.landmarks)  # pixels per torso length, to compare keypoints
        if (self._lies_on(observation, others, config.track_behind_max_overlap)
                or not looks_like(track, observation, config.track_reid_max_distance)
                or any(same_body_points(observation.keypoints, keypoints, scale, config)
                       for keypoints in others_keypoints or [])):
            return None
        self.written_keypoints(image, observation)
        if self._lies_on(observation, others, config.track_backfill_keypoints_max_overlap):
            observation.keypoints[:, 2] = 0.0
        self._record(track, observation, frame_id)
        track.looked_again.append(frame_id)
        return observation

    def keypoints_behind(self, image: np.ndarray, labels: np.ndarray, label: int, region: Region
                         ) -> tuple[np.ndarray, np.ndarray] | None:
        """(keypoints [17, 3] as recorded, 3D points [17, 4] as recorded) of the person ``label`` of ``labels``
        [H, W] (the final depth-ordered labels of ``image``) looked for in ``region`` with every other person's
        pixels painted over as for the written keypoints (glimpse.ingest.behind), joints on those pixels written as
        not seen; None when the model finds nobody there."""
        config = self.config
        people = labels != NOBODY
        others = people & (labels != label)
        painted = self._painted_over(image, others, people, image, config.keypoints_paint_still_with)
        observation = self.observe(painted, region)
        if observation is None:
            return None
        self.written_keypoints(painted, observation)
        keypoints = recorded_keypoints(observation.keypoints, labels.shape, config.keypoint_min_confidence)
        keypoints[joints_on_others(keypoints[:, :2], labels, label)] = 0.0
        return keypoints, recorded_relative3d(observation, keypoints[:, 2])

    def _resolve_duplicates(self, followed: dict[int, Observation]) -> list[int]:
        """Of two observations of one person drop the piece (a part taken for a person), or the one whose
        appearance matches its track worse; returns the tracks that lost theirs."""
        tracks = {t.index: t for t in self.tracks}
        losers = []
        indices = sorted(followed)
        for i, a in enumerate(indices):
            for b in indices[i + 1:]:
                if a not in followed or b not in followed:
                    continue
                seen_a, seen_b = followed[a], followed[b]
                if part_of(seen_a, seen_b, self.config.track_part_scale):
                    loser = a  # a piece of b's person
                elif part_of(seen_b, seen_a, self.config.track_part_scale):
                    loser = b
                elif same_person(seen_a.landmarks, seen_b.landmarks, self.config):
                    cost_a = appearance_distance(tracks[a].look, seen_a.look)
                    cost_b = appearance_distance(tracks[b].look, seen_b.look)
                    loser = b if cost_a <= cost_b else a
                else:
                    continue
                del followed[loser]
                losers.append(loser)
        return losers

    def _hidden_by_others(self, live: list[Track], followed: dict[int, Observation]) -> set[int]:
        """Tracks not seen this frame whose predicted region overlaps the region of someone found: the person may
        be behind them, where the landmark model sees two people in one crop and gives up."""
        regions = np.array([o.landmarks.region.box() for o in followed.values()]).reshape(-1, 4)
        if not len(regions):
            return set()
        return {t.index for t in live if t.index not in followed
                and box_iou(t.predicted_region().box()[None], regions).max() > 0}

    def body_pixels(self, observation: Observation) -> np.ndarray:
        """[H, W] bool: the pixels of the observation's segmentation that lie on its own body (near its skeleton;
        the segmentation also covers other people in the crop)."""
        if observation.body is None:
            near = observed_skeleton_distance(observation) < self.config.mask_body_radius
            observation.body = observation.mask & near
        return observation.body

    def _bodies(self, observations: list[Observation], shape: tuple[int, int]) -> np.ndarray:
        """[H, W] bool: the union of the observations' body pixels (:meth:`body_pixels`)."""
        union = np.zeros(shape, bool)
        for observation in observations:
            union |= self.body_pixels(observation)
        return union

    def _painted_over(self, image: np.ndarray, pixels: np.ndarray, people: np.ndarray | None = None,
                      frame: np.ndarray | None = None,
                      still_with: Literal["surroundings", "beside"] | None = None) -> np.ndarray:
        """A copy of ``image`` with ``pixels`` [H, W] bool replaced by the background plate, and where there is no
        plate, by the colour of their surroundings (:func:`surroundings_fill`). Where the plate shows what the frame
        shows (``frame``, default ``image``: the frame unpainted; within ``foreground_threshold``, in regions at
        least STILL_WIDTH wide) a person stood still for most of the video and painting them with the plate would
        paint them back: there, the colour of their surroundings, or with ``still_with`` (default
        ``paint_still_with``) ``beside`` the plate's texture from beside them where it has some (:func:`beside_fill`,
        from pixels where the frame shows the plate and that are not on ``people`` [H, W] bool, the bodies of
        everyone found: nobody's texture is copied)."""
        frame = image if frame is None else frame
        still_with = self.config.paint_still_with if still_with is None else still_with
        painted = image.copy()
        to_fill = pixels
        still_px = round(STILL_WIDTH * image.shape[0])
        if self.plate is not None:
            painted[pixels] = self.plate[pixels]
            still = np.zeros_like(pixels)
            still[pixels] = ~differs_from_plate(frame[pixels], self.plate[pixels], self.config.foreground_threshold)
            kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (max(1, still_px),) * 2)
            to_fill = cv2.morphologyEx(still.astype(np.uint8), cv2.MORPH_OPEN, kernel).astype(bool)
        if to_fill.any():
            painted[to_fill] = surroundings_fill(image, pixels)[to_fill]
            if self.plate is not None and still_with == "beside":
                blocked = pixels | differs_from_plate(frame, self.plate, self.config.foreground_threshold)
                fill, given = beside_fill(self.plate, to_fill, still_px,
                                          blocked if people is None else blocked | people)
                painted[given] = fill[given]
        return painted

    def _look_behind_all(self, image: np.ndarray, followed: dict[int, Observation], tracks: list[Track]) -> None:
        """Each of ``tracks`` in turn looks behind the people ``followed`` this frame (:meth:`_look_behind`), the
        people the tracks before it found there painted over too (the person behind the person found behind). A
        track that finds nothing so, where others found someone, looks again past the people followed alone:
        when it finds one of those finds, who looks like it better by more than ``track_reclaim_margin``, it takes
        them (a walker passing someone who stands behind: both tracks' regions lie over the walker, and the first
        to look would take them), and the track that lost them looks again."""
        direct = dict(followed)
        found: dict[int, Observation] = {}
        for track in tracks:
            observation = self._look_behind(image, followed, track)
            if observation is None and found:
                observation = self._take_from_others(image, direct, followed, found, track, tracks)
            if observation is not None:
                followed[track.index] = found[track.index] = observation

    def _take_from_others(self, image: np.ndarray, direct: dict[int, Observation], followed: dict[int, Observation],
                          found: dict[int, Observation], track: Track, tracks: list[Track]) -> Observation | None:
        """What ``track`` finds behind the ``direct``ly followed people when that is one of the others' ``found``
        and looks like ``track`` better by the reclaim margin (then the loser's find is dropped, and it looks
        again with everything found painted over); else None."""
        observation = self._look_behind(image, direct, track)
        if observation is None:
            return None
        by_index = {t.index: t for t in tracks}
        distance = appearance_distance(track.look, observation.look)
        for other, find in found.items():
            if (one_person(observation, find, self.config)
                    and distance + self.config.track_reclaim_margin < appearance_distance(by_index[other].look,
                                                                                          find.look)):
                del found[other], followed[other]
                followed[track.index] = observation
                again = self._look_behind(image, followed, by_index[other])
                if again is not None:
                    followed[other] = found[other] = again
                return observation
        return None

    def _look_behind(self, image: np.ndarray, followed: dict[int, Observation], track: Track) -> Observation | None:
        """A track whose region slid onto, or overlaps, someone already ``followed`` looks again with the found
        people painted over (:meth:`_painted_over`) where they are nearer to their own skeleton than to the
        track's expected one: the person hidden behind them, if still visible, is who remains (returned; None
        when nobody is, or they lie mostly on the people found or do not look like the track)."""
        found = list(followed.values())
        bodies = self._bodies(found, image.shape[:2])
        # pixels nearer to where this person should be than to anyone found stay
        own = skeleton_distance(track.predicted_landmarks(), bodies.shape)
        hidden = bodies & (np.min([observed_skeleton_distance(o) for o in found], axis=0) <= own)
        observation = self.observe(self._painted_over(image, hidden, bodies), track.predicted_region(), image,
                                   hidden)
        if observation is None or self._taken(observation, found, self.config.track_behind_max_overlap, bodies):
            return None
        # someone else was behind them: a lost track comes back only as it looked, a followed one as when followed
        limit = self.config.track_reid_max_distance if track.missing else self.config.track_follow_max_distance
        return observation if looks_like(track, observation, limit) else None

    def _find_new(self, image: np.ndarray, observed: list[Observation]) -> list[Observation]:
        fresh: list[Observation] = []
        painted, painted_for, bodies = image, 0, None  # the people found painted over: the model sees who they hide
        for region in detector_regions(self.model, image, self.config, self.detector):
            boxes = np.array([o.landmarks.region.box() for o in observed + fresh]).reshape(-1, 4)
            if len(boxes) and box_iou(region.box()[None], boxes).max() > self.config.track_covered_iou:
                continue
            if painted_for != len(observed + fresh):
                painted_for = len(observed + fresh)
                bodies = self._bodies(observed + fresh, image.shape[:2])
                painted = self._painted_over(image, bodies, bodies)
            self._keep_new(self.observe(painted, region, image, bodies), observed, fresh, bodies)
        if self.plate is None:
            return fresh
        # unexplained foreground (never covered by a found person, by construction), again after each round that
        # found someone: what is left of a blob once they are explained may be another person
        sides = [t.region.side for t in self.tracks if t.missing == 0]
        person_side = float(np.median(sides)) if sides else 0.0
        tried = np.zeros((0, 4))
        for _ in range(self.config.foreground_rounds):
            explained = self._bodies(observed + fresh, image.shape[:2])
            found_before = len(fresh)
            for candidate in foreground_candidates(image, self.plate, explained, self.config, person_side):
                box = candidate.region.box()
                if len(tried) and box_iou(box[None], tried).max() > SAME_REGION_IOU:
                    continue
                tried = np.concatenate([tried, box[None]])
                painted = self._painted_over(image, candidate.paint, explained)
                observation = self.observe(painted, candidate.region, image, candidate.paint)
                if observation is not None and self._shown_by_plate(image, observation):
                    continue
                self._keep_new(observation, observed, fresh)
            if len(fresh) == found_before:
                break
        return fresh

    def _shown_by_plate(self, image: np.ndarray, observation: Observation) -> bool:
        """Whether less than ``foreground_min_differing`` of the observation's body pixels differ from the plate in
        ``image``: what the landmark model fitted in a foreground region is something the plate shows (a painted
        pillar beside the person who made the foreground), not who made it."""
        body = self.body_pixels(observation)
        if not body.any():
            return False
        differing = differs_from_plate(image[body], self.plate[body], self.config.foreground_threshold)
        return float(differing.mean()) < self.config.foreground_min_differing

    def _keep_new(self, observation: Observation | None, observed: list[Observation], fresh: list[Observation],
                  found_bodies: np.ndarray | None = None) -> None:
        """Add a candidate's observation to ``fresh`` unless it is nobody or :meth:`_taken` (``found_bodies``: the
        union of ``observed + fresh``'s bodies when the caller has it)."""
        if observation is not None and not self._taken(observation, observed + fresh,
                                                       self.config.track_new_max_overlap, found_bodies):
            fresh.append(observation)

    def _taken(self, observation: Observation, found: list[Observation], max_overlap: float,
               found_bodies: np.ndarray | None = None) -> bool:
        """Whether an observation shows someone already ``found``, or lies mostly on their bodies (more than
        ``max_overlap`` of its own body's pixels): a fit that took the limbs of the person in front for those of
        someone they hide, whose mask would take the front person's pixels. ``found_bodies``: their union
        (:meth:`_bodies`), when the caller has it already."""
        if any(one_person(observation, other, self.config) for other in found):
            return True
        if not found:
            return False
        others = self._bodies(found, observation.mask.shape) if found_bodies is None else found_bodies
        return self._lies_on(observation, others, max_overlap)

    def _lies_on(self, observation: Observation, pixels: np.ndarray, max_overlap: float) -> bool:
        """Whether more than ``max_overlap`` of the observation's body pixels (:meth:`body_pixels`) lie on
        ``pixels`` [H, W] bool."""
        body = self.body_pixels(observation)
        return np.count_nonzero(body & pixels) > max_overlap * max(np.count_nonzero(body), 1)

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
            track = Track(len(self.tracks), observation.landmarks, observation.look)
            self.tracks.append(track)
            pairs.append((track, observation))
        return pairs

    def _clear_of(self, observation: Observation, others: list[Observation]) -> bool:
        """Whether at most ``appearance_update_max_overlap`` of the observation's body pixels lie on the ``others``'
        bodies (:meth:`body_pixels`)."""
        return not others or not self._lies_on(observation, self._bodies(others, observation.mask.shape),
                                               self.config.appearance_update_max_overlap)

    def _update(self, track: Track, observation: Observation, frame_id: int, clear: bool = True) -> None:
        """Move the track on to ``observation`` (landmarks, velocity, suspected jumps) and record it; its
        appearance follows the observation's only when ``clear`` (not lying on the other people found: the
        appearance of a fit half on someone else mixes the two)."""
        config = self.config
        landmarks = observation.landmarks
        if track.frames:
            step = landmarks.next_region.centre - track.region.centre
            track.velocity = (1 - VELOCITY_SMOOTHING) * track.velocity + VELOCITY_SMOOTHING * step / (1 + track.missing)
            previous = track.boxes[-1]
            jump = np.linalg.norm(box_centre(observation.box) - box_centre(previous))
            if jump > config.track_switch_distance * max(previous[3] - previous[1], 1.0) * (1 + track.missing):
                track.jumps.append(frame_id)
        track.landmarks = landmarks
        track.missing = 0
        if clear:
            track.look = blend(track.look, observation.look, config.appearance_update)
        self._record(track, observation, frame_id)

    def _record(self, track: Track, observation: Observation, frame_id: int) -> None:
        """Add the observation's keypoints (those outside the image or below ``keypoint_min_confidence`` at
        confidence 0), 3D landmarks, box and legs' dispute to the track's per-frame lists, in frame order."""
        keypoints = recorded_keypoints(observation.keypoints, observation.mask.shape,
                                       self.config.keypoint_min_confidence)
        at = bisect.bisect(track.frames, frame_id)
        track.frames.insert(at, frame_id)
        track.keypoints.insert(at, keypoints)
        track.relative3d.insert(at, recorded_relative3d(observation, keypoints[:, 2]))
        track.boxes.insert(at, observation.box)
        track.legs_disputed.insert(at, observation.legs_disputed)
