"""``glimpse ingest VIDEO SCENE_DIR``: an ordinary video -> a glimpse-scene/1 folder.

Three streaming passes (frames decoded one at a time; the tracking pass also holds its last
``track_backfill_frames`` frames at the tracking size):

1. survey (glimpse.ingest.survey): frame times, the scene's frames, camera motion, the background plate;
2. track (glimpse.ingest.tracker): every chosen frame is written to the scene (at ``max_side``) and its
   people are followed, found and re-identified (at ``track_max_side``); each frame's depth-ordered person
   labels go to a work folder; a track that finds its person again looks again at the frames it missed
   (glimpse.ingest.backfill: the last ``track_backfill_frames`` frames are held for it);
3. write: the tracks kept (long, large and upright enough: glimpse.ingest.upright); per person its masks and
   COCO-17 keypoints (left and right made consistent along the track, frames
   squeezed at the border and joints hidden behind others left out: glimpse.ingest.sides, glimpse.ingest.truncation,
   glimpse.ingest.occlusion), on a fixed camera masks for the frames inside a track's gap from what differs from
   a plate without the people (glimpse.ingest.gap_masks; the frames decoded twice more, for that plate and for
   the masks), the preview video and the tracks report
   (``ingest/preview.mp4``, ``ingest/tracks.json``; the scene format ignores them); scene.yaml's overrides
   carry stage 02's settings for a detector's keypoints (``fit_overrides``).

The scene is staged beside SCENE_DIR and renamed into place only when complete and valid: a failed ingest
leaves a previous scene there untouched. The tracking pass keeps its labels and, every ``checkpoint_frames``
frames, its state (glimpse.ingest.checkpoint) in SCENE_DIR.ingest-work/: an interrupted ingest run again with
the same video and parameters goes on from the last checkpoint; the folder is removed when the scene is done.
"""

from __future__ import annotations

import json
import logging
import re
import shutil
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict
from functools import partial
from math import ceil
from pathlib import Path

import cv2
import numpy as np

from glimpse.config import REPO_ROOT
from glimpse.errors import GlimpseError
from glimpse.ingest.backfill import fill_gaps, look_before_start, open_gaps
from glimpse.ingest.behind import behind_plan, with_keypoints
from glimpse.ingest.blazepose import BlazePose
from glimpse.ingest.checkpoint import fingerprint, load_checkpoint, save_checkpoint
from glimpse.ingest.config import SCENE_UNCHANGED_BY, IngestConfig
from glimpse.ingest.onnx_models import OnnxDetector, OnnxPose
from glimpse.ingest.report import (
    PREVIEW_FILE,
    REPORT_FILE,
    PersonTrack,
    labels_from_masks,
    preview_frames,
    report_table,
    tracks_report,
)
from glimpse.ingest.sides import consistent_sides
from glimpse.ingest.smoothing import smooth_keypoints
from glimpse.ingest.survey import Survey, intrinsics_from_focal, survey_video
from glimpse.ingest.depth_order import depth_ordered_labels
from glimpse.ingest.gap_masks import (Sighting, gap_frames, gap_mask, interpolated_box, kept_only, mask_box,
                                      mean_colours, people_free_plate, sightings_in, taken_back, with_mask_frames)
from glimpse.ingest.occlusion import hidden_joints
from glimpse.ingest.mask_snap import snapped_masks
from glimpse.ingest.observation import Track
from glimpse.ingest.tracker import Tracker
from glimpse.ingest.truncation import squeezed_at_border
from glimpse.ingest.upright import upside_down_share
from glimpse.io.images import frame_name, read_rgb
from glimpse.io.progress import progress
from glimpse.io.json_file import write_json
from glimpse.io.video import iter_video_frames, resized, write_mp4
from glimpse.scene.writer import SceneWriter, scene_folder

log = logging.getLogger("glimpse")

SCENE_MASK_COVERAGE = 0.5  # a scene pixel is a person's when the person covers more than half of it
WORK_SUFFIX = ".ingest-work"  # SCENE_DIR + this: labels and checkpoints of an unfinished ingest
CHECKPOINT_FILE = "checkpoint.npz"


def blazepose_folder(config: IngestConfig) -> Path:
    folder = Path(config.blazepose_dir)
    return folder if folder.is_absolute() else REPO_ROOT / folder


def user_detector(config: IngestConfig) -> OnnxDetector | None:
    """The ONNX detector the parameters ask for (None: BlazePose's own)."""
    if config.detector != "onnx":
        return None
    return OnnxDetector(config.detector_onnx_path, config.detector_onnx_kind, config.detector_onnx_min_score,
                        config.threads)


def user_pose(config: IngestConfig) -> OnnxPose | None:
    """The ONNX pose model the parameters ask for (None: BlazePose's landmarks)."""
    if config.pose != "onnx":
        return None
    return OnnxPose(config.pose_onnx_path, config.pose_onnx_box_padding, config.threads)


def _label_path(work: Path, frame_id: int) -> Path:
    return work / "labels" / f"{frame_name(frame_id)}.png"


def _read_labels(work: Path, frame_id: int) -> np.ndarray:
    """[H, W] uint16 at the tracking size: a frame's depth-ordered person labels from the work folder."""
    return cv2.imread(str(_label_path(work, frame_id)), cv2.IMREAD_UNCHANGED)


def _write_labels(work: Path, frame_id: int, labels: np.ndarray) -> None:
    cv2.imwrite(str(_label_path(work, frame_id)), labels)


def _chosen_frames(path: Path, survey: Survey, desc: str) -> Iterator[tuple[int, np.ndarray]]:
    """(scene frame id, [H, W, 3] uint8 at the decoded size) of the survey's chosen frames, decoded again."""
    for index, rgb in iter_video_frames(path, survey.chosen, desc):
        yield survey.chosen[index], rgb


def _to_scene_pixels(points: np.ndarray, survey: Survey) -> np.ndarray:
    """[..., 2] tracking-size pixel coordinates -> scene-size ones (pixel centres kept)."""
    ratio = np.array([survey.width / survey.track_width, survey.height / survey.track_height])
    return (points + 0.5) * ratio - 0.5


def _keypoints_to_scene_pixels(keypoints: np.ndarray, survey: Survey) -> np.ndarray:
    """[..., 3] tracking-size keypoints (pixels, confidence) -> scene-size ones, missing ones (confidence 0) at 0."""
    found = keypoints[..., 2:] > 0
    return np.concatenate([np.where(found, _to_scene_pixels(keypoints[..., :2], survey), 0.0), keypoints[..., 2:]], -1)


def _to_tracking_pixels(points: np.ndarray, survey: Survey) -> np.ndarray:
    """[..., 2] scene-size pixel coordinates -> tracking-size ones (the inverse of :func:`_to_scene_pixels`)."""
    ratio = np.array([survey.track_width / survey.width, survey.track_height / survey.height])
    return (points + 0.5) * ratio - 0.5


def _kept_people(tracks: list[Track], survey: Survey, config: IngestConfig,
                 labels_of: Callable[[int], np.ndarray]) -> tuple[list[PersonTrack], dict]:
    """Tracks seen in at least ``track_min_frames`` frames (not counting frames looked at again) whose box is usually
    (median over their frames) at least ``track_min_height`` of the frame's height and upside down in at most
    ``track_max_upside_down`` of the frames showing their torso (glimpse.ingest.upright), named p0, p1, ... in order of
    first appearance, their keypoints' left and right (and their legs', on a static camera) made consistent along
    the track (glimpse.ingest.sides), squeezed frames and joints hidden behind others (on the pixels of someone
    nearer in ``labels_of(frame id)``, the tracking-size labels: glimpse.ingest.occlusion.hidden_joints) written as
    not seen, smoothed over time and, with their boxes, in scene pixels; and how many tracks were dropped, by
    reason."""
    long_enough = [t for t in tracks if len(t.frames) - len(t.looked_again) >= config.track_min_frames]
    large_enough = [t for t in long_enough if _median_height(t) >= config.track_min_height * survey.track_height]
    kept = sorted((t for t in large_enough
                   if upside_down_share(np.stack(t.keypoints)) <= config.track_max_upside_down),
                  key=lambda t: (t.frames[0], t.index))
    dropped = {"short": len(tracks) - len(long_enough), "small": len(long_enough) - len(large_enough),
               "upside_down": len(large_enough) - len(kept)}
    named = [_sides_and_border(track, survey, config) for track in kept]
    if config.hide_joints_on_others:
        hidden = hidden_joints([(track.index + 1, track.frames, keypoints) for track, (keypoints, *_) in
                                zip(kept, named)], labels_of, config.mask_depth_frames)
        for (keypoints, relative3d, *_), behind in zip(named, hidden):
            keypoints[..., 2][behind] = 0.0
            relative3d[..., 3][behind] = 0.0
    people = []
    for k, (track, (keypoints, relative3d, exchange, squeezed, legs)) in enumerate(zip(kept, named)):
        frames = np.array(track.frames)
        keypoints = smooth_keypoints(frames, keypoints, config.keypoint_smoothing_frames)
        keypoints = _keypoints_to_scene_pixels(keypoints, survey)
        boxes = _to_scene_pixels(np.stack(track.boxes).reshape(-1, 2, 2), survey).reshape(-1, 4)
        relative3d = smooth_keypoints(frames, relative3d, config.keypoint_smoothing_frames)
        people.append(PersonTrack(f"p{k}", track.index + 1, list(track.frames), keypoints, relative3d, boxes,
                                  list(track.reidentified), list(track.jumps),
                                  [f for f, e in zip(track.frames, exchange) if e],
                                  [f for f, e in zip(track.frames, squeezed) if e],
                                  [f for f, e in zip(track.frames, legs) if e], sorted(track.looked_again)))
    return people, dropped


def _sides_and_border(track: Track, survey: Survey, config: IngestConfig
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A track's (keypoints [T, 17, 3], relative3d [T, 17, 4], [T] bool frames whose sides were exchanged,
    [T] bool frames squeezed at the border, [T] bool frames whose legs were exchanged), at the tracking size: left
    and right (and the legs) made consistent (:func:`consistent_sides`), squeezed frames (glimpse.ingest.truncation)
    written as not seen."""
    frames = np.array(track.frames)
    keypoints, relative3d, exchange, legs = consistent_sides(
        frames, np.stack(track.keypoints), np.stack(track.relative3d), np.array(track.legs_disputed),
        survey.static, survey.fps, config)
    squeezed = np.zeros(len(track.frames), bool)
    if config.border_squeeze_max > 0:
        squeezed = squeezed_at_border(frames / survey.fps, keypoints, np.stack(track.boxes),
                                      (survey.track_width, survey.track_height), config.border_squeeze_margin,
                                      config.border_squeeze_window_s, config.border_squeeze_max)
        keypoints[squeezed, :, 2] = 0.0
        relative3d[squeezed, :, 3] = 0.0
    return keypoints, relative3d, exchange, squeezed, legs


def _masks_in_gaps(video: Path, survey: Survey, config: IngestConfig, people: list[PersonTrack],
                   work: Path) -> tuple[list[PersonTrack], dict[int, list[tuple[int, np.ndarray]]]]:
    """``people`` with masks in the frames inside their tracks' gaps where what differs from the plate is theirs
    (glimpse.ingest.gap_masks; their keypoints there all at confidence 0), the frames decoded again; and those
    masks, frame id -> [(label, flat indices of its pixels in the tracking-size labels)]. The labels in ``work``
    stay as tracking wrote them (an interrupted ingest run again sees the same). Two more passes over the frames:
    one for the plate without the people (glimpse.ingest.gap_masks.people_free_plate) and everyone's masks in the
    frames around the gaps (their boxes, areas and colours), one for the masks."""
    gaps = {person.pid: gap_frames(person.frames, config.gap_mask_max_frames) for person in people}
    needed = {gap.frame_id for person_gaps in gaps.values() for gap in person_gaps}
    around = {f for person_gaps in gaps.values() for gap in person_gaps for f in (gap.before, gap.after)}
    added: dict[str, dict[int, np.ndarray]] = {person.pid: {} for person in people}  # frame id -> scene box
    additions: dict[int, list[tuple[int, np.ndarray]]] = {}
    if not needed:
        return people, additions
    track_size = (survey.track_width, survey.track_height)
    sampled = set(list(survey.chosen.values())[::max(1, ceil(len(survey.chosen) / config.plate_frames))])
    kept = [person.label for person in people]
    samples = []
    sightings: dict[tuple[int, int], Sighting] = {}  # (label, frame id around a gap) -> that person's mask there
    for frame_id, rgb in _chosen_frames(video, survey, "a plate without the people"):
        if frame_id in sampled or frame_id in around:
            image, labels = resized(rgb, track_size), _read_labels(work, frame_id)
        if frame_id in sampled:
            samples.append((image, labels > 0))  # anyone found, a track dropped later included
        if frame_id in around:
            sightings.update(sightings_in(image, kept_only(labels, kept), frame_id, config.gap_mask_colour_bins))
    plate = people_free_plate(np.stack([image for image, _ in samples]), np.stack([found for _, found in samples]),
                              survey.plate, round(config.gap_mask_plate_margin * survey.track_height))
    smoothing_px = config.gap_mask_colour_smoothing * survey.track_height

    for frame_id, rgb in _chosen_frames(video, survey, "masks in the tracks' gaps"):
        if frame_id not in needed:
            continue
        image, labels = resized(rgb, track_size), kept_only(_read_labels(work, frame_id), kept)
        for person in people:
            for gap in (g for g in gaps[person.pid] if g.frame_id == frame_id):
                before, after = (sightings.get((person.label, f)) for f in (gap.before, gap.after))
                if before is None or after is None:
                    continue
                box = interpolated_box(before.box, after.box, gap.fraction, config.gap_mask_box_grow)
                taken = None
                if config.gap_mask_take_ratio > 0:
                    theirs = {label: mean_colours(gap, label, sightings) for label in kept if label != person.label}
                    taken = taken_back(image, labels, box, mean_colours(gap, person.label, sightings), theirs,
                                       config.gap_mask_take_ratio, smoothing_px)
                mine = gap_mask(image, plate, labels, box, (before.area + after.area) / 2, config, taken)
                if mine is not None:
                    labels[mine] = person.label
                    additions.setdefault(frame_id, []).append((person.label, np.flatnonzero(mine)))
                    added[person.pid][frame_id] = _to_scene_pixels(mask_box(mine).reshape(2, 2), survey).reshape(4)
    return [with_mask_frames(person, added[person.pid]) for person in people], additions


def _keypoints_behind(video: Path, survey: Survey, tracker: Tracker, people: list[PersonTrack],
                      labels_of: Callable[[int], np.ndarray]) -> list[PersonTrack]:
    """``people`` with their keypoints looked for again where they were behind someone (glimpse.ingest.behind),
    the frames decoded once more (only when someone was)."""
    plan = behind_plan(people, labels_of, partial(_to_tracking_pixels, survey=survey), tracker.config)
    if not plan:
        return people
    track_size = (survey.track_width, survey.track_height)
    for frame_id, rgb in _chosen_frames(video, survey, "keypoints behind others"):
        if frame_id not in plan:
            continue
        image, labels = resized(rgb, track_size), labels_of(frame_id)
        for index, region in plan[frame_id]:
            found = tracker.keypoints_behind(image, labels, people[index].label, region)
            if found is None:
                continue
            keypoints, relative3d = found
            people[index] = with_keypoints(people[index], frame_id, _keypoints_to_scene_pixels(keypoints, survey),
                                           relative3d)
    return people


def _labels_with(work: Path, additions: dict[int, list[tuple[int, np.ndarray]]], frame_id: int) -> np.ndarray:
    """A frame's tracking-size labels (``work``) with the masks ``_masks_in_gaps`` added."""
    labels = _read_labels(work, frame_id)
    for label, pixels in additions.get(frame_id, []):
        labels.flat[pixels] = label
    return labels


def _median_height(track: Track) -> float:
    """Pixels: the median height of a track's landmark boxes."""
    return float(np.median([box[3] - box[1] for box in track.boxes]))


def _person_mask(labels: np.ndarray, label: int, survey: Survey) -> np.ndarray:
    """[H, W] bool at the scene's size: the pixels of tracking-size ``labels`` that belong to ``label``."""
    mine = (labels == label).astype(np.float32)
    return resized(mine, (survey.width, survey.height)) > SCENE_MASK_COVERAGE


def _write_masks(writer: SceneWriter, people: list[PersonTrack], labels_of: Callable[[int], np.ndarray],
                 survey: Survey, config: IngestConfig) -> None:
    """Each person's mask in each of their frames, at the scene's size: those from the segmentation snapped to the
    frame's edges (glimpse.ingest.mask_snap; ``mask_snap_radius`` 0: as the labels give them), those from the plate
    in a track's gap (already at the pixels' own edges, often slivers the filter would thin away) as they are."""
    present: dict[int, list[PersonTrack]] = {}
    for person in people:
        for frame_id in person.frames:
            present.setdefault(frame_id, []).append(person)
    radius = round(config.mask_snap_radius * max(survey.width, survey.height))
    for frame_id, here in progress(sorted(present.items()), desc="writing masks", unit="frame", leave=False):
        labels = labels_of(frame_id)
        masks = {person.pid: _person_mask(labels, person.label, survey) for person in here}
        segmented = [person.pid for person in here if frame_id not in person.masks_from_foreground]
        if radius > 0 and segmented:
            frame = read_rgb(writer.written(f"frames/{frame_name(frame_id)}.png"))
            from_plate = np.zeros(frame.shape[:2], bool)
            for person in here:
                if person.pid not in segmented:
                    from_plate |= masks[person.pid]
            snapped = snapped_masks(frame, [masks[pid] for pid in segmented], radius, config.mask_snap_eps)
            masks.update({pid: mask & ~from_plate for pid, mask in zip(segmented, snapped)})
        for person in here:
            writer.person_mask(person.pid, frame_id, masks[person.pid])


def _written_labels(writer: SceneWriter, people: list[PersonTrack], frame_id: int, survey: Survey) -> np.ndarray:
    """[H, W] uint16 at the scene's size: the kept people's labels in one frame, from the masks written."""
    here = [(person.label, writer.written(f"humans/{person.pid}/masks/{frame_name(frame_id)}.png"))
            for person in people if frame_id in person.frames]
    return labels_from_masks(survey.height, survey.width, here)


def _facts(video: Path, survey: Survey, config: IngestConfig, track_seconds: float, frames_done: int) -> dict:
    """The video's facts and the ingest's timings, for the tracks report (``frames_done``: frames a
    checkpoint had tracked before this run)."""
    return {
        "video": str(video), "video_size": [survey.info.width, survey.info.height],
        "rotation_deg": survey.info.rotation_deg, "scene_size": [survey.width, survey.height],
        "tracking_size": [survey.track_width, survey.track_height],
        "fps": survey.fps, "frames": len(survey.chosen), "decoded_frames": survey.decoded,
        "container_frames": survey.info.frame_count, "truncated": survey.truncated,
        "frame_limit": config.max_frames if survey.limited else None,
        "segment_s": _segment_seconds(survey),
        "camera_motion": "static" if survey.static else "moving", "camera_motion_measure": survey.motion.motion,
        "focal_35mm_equivalent": survey.focal_35mm,
        "intrinsics": ("cameras.json from the container's focal length" if survey.focal_35mm is not None
                       else "none written: stage 01 uses 01_sfm.static_fov_deg (static) or estimates the focal "
                            "length in SfM (moving)"),
        "seconds": {"tracking": track_seconds},
        "resumed_after_frames": frames_done,
        "parameters": scene_parameters(config),
        "tracking_fps": (len(survey.chosen) - frames_done) / max(track_seconds, 1e-9),
    }


def scene_name_of(video: Path) -> str:
    """The scene name a video gets: its file name without extension, every character a scene name may not
    hold (SCENE_FORMAT.md: letters, digits, _, - and .) replaced by _."""
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", Path(video).stem)
    return "video" if set(name) <= {"."} else name


def default_scene_dir(video: Path, out_root: Path) -> Path:
    """Where ``make all VIDEO=...`` keeps a video's scene when no SCENE is given: OUT/scenes/<scene name>."""
    return Path(out_root) / "scenes" / scene_name_of(video)


def scene_parameters(config: IngestConfig) -> dict:
    """The ingest parameters a scene depends on (the tracks report's ``parameters``), as JSON values."""
    return json.loads(json.dumps({k: v for k, v in asdict(config).items() if k not in SCENE_UNCHANGED_BY}))


def why_ingest_again(video: Path, scene_dir: Path, config: IngestConfig) -> str | None:
    """Why ``scene_dir`` is not what ingesting ``video`` with ``config`` would make (None: it is): no scene yet, a
    video newer than the scene, or ingest parameters other than those its tracks report records (a parameter the
    report does not name, from an older ingest, counts as unchanged)."""
    stamp = Path(scene_dir) / "scene.yaml"
    if not stamp.is_file():
        return "no scene yet"
    if Path(video).stat().st_mtime_ns > stamp.stat().st_mtime_ns:
        return "the video is newer than the scene"
    report = Path(scene_dir) / REPORT_FILE
    recorded = json.loads(report.read_text()).get("parameters", {}) if report.is_file() else {}
    changed = [f"ingest.{key} {recorded[key]!r} -> {value!r}" for key, value in scene_parameters(config).items()
               if key in recorded and recorded[key] != value]
    return f"ingest parameters changed since it was ingested: {', '.join(changed)}" if changed else None


def fit_overrides(config: IngestConfig) -> dict[str, dict]:
    """The scene.yaml overrides an ingested scene carries: stage 02's settings for a detector's keypoints (the size
    prior, the keypoints' noise, unseen limbs left at rest by the pose hypotheses, the floor's tilt from the torso
    axes)."""
    for name, unit in (("fit_size_sigma", "relative"), ("fit_keypoint_noise_m", "metres")):
        if not getattr(config, name) >= 0:
            raise GlimpseError(f"ingest.{name} must be 0 (write none) or more ({unit}), found {getattr(config, name)}")
    fit: dict = {}
    weights = {key: value for key, value in (("size_sigma", config.fit_size_sigma),
                                             ("keypoint_noise_m", config.fit_keypoint_noise_m)) if value > 0}
    if weights:
        fit["weights"] = weights
    if config.fit_unseen_limbs_at_rest:
        fit["unseen_limbs_at_rest"] = True
    if config.fit_up_from_torsos:
        fit["ground"] = {"up_from": "torso_axes"}
    return {"02_smpl_fit": fit} if fit else {}


def ingest(video: Path, scene_dir: Path, config: IngestConfig) -> dict:
    """Ingest ``video`` into ``scene_dir`` (see the module docstring); returns the tracks report."""
    video, scene_dir = Path(video), scene_folder(scene_dir)
    started = time.perf_counter()
    survey = survey_video(video, config)
    model = BlazePose(blazepose_folder(config), config.threads)
    detector, pose = user_detector(config), user_pose(config)
    log.info("%s: %dx%d at %.3g fps -> %d frames at %dx%d, camera motion %.3g of the diagonal", video,
             survey.info.width, survey.info.height, survey.fps, len(survey.chosen), survey.width, survey.height,
             survey.motion.motion)
    scene_dir.parent.mkdir(parents=True, exist_ok=True)
    writer = SceneWriter(scene_dir, scene_name_of(video), survey.fps, "static" if survey.static else "moving",
                         overrides=fit_overrides(config))
    work = scene_dir.with_name(scene_dir.name + WORK_SUFFIX)
    tracker = Tracker(model, config, survey.plate, detector, pose)
    key = fingerprint(video, config)
    resumed = load_checkpoint(work / CHECKPOINT_FILE, key)
    if resumed is None:
        shutil.rmtree(work, ignore_errors=True)
        frames_done = 0
    else:
        tracker.tracks, frames_done = resumed
        log.info("%s: going on from the checkpoint in %s (%d of %d frames tracked)", video, work, frames_done,
                 len(survey.chosen))
    (work / "labels").mkdir(parents=True, exist_ok=True)
    try:
        report = _track_and_write(video, survey, config, writer, work, tracker, frames_done, key)
        report["seconds"]["total"] = time.perf_counter() - started
        write_json(writer.side_file(REPORT_FILE), report)
        writer.finish()
    except GlimpseError:
        shutil.rmtree(writer.staging, ignore_errors=True)  # a previous scene at scene_dir stays as it was
        shutil.rmtree(work, ignore_errors=True)  # a verdict (no person, an invalid scene): nothing to go on from
        raise
    except BaseException:
        shutil.rmtree(writer.staging, ignore_errors=True)
        if (work / CHECKPOINT_FILE).exists():
            print(f"ingest interrupted; its tracking is saved in {work}: run the same command again to go on "
                  "from there")
        raise
    shutil.rmtree(work, ignore_errors=True)
    _announce(video, scene_dir, survey, report, config)
    return report


def _track_and_write(video: Path, survey: Survey, config: IngestConfig, writer: SceneWriter, work: Path,
                     tracker: Tracker, frames_done: int, key: str) -> dict:
    """Passes 2 and 3 (see the module docstring) into ``writer``, the tracking going on after the first
    ``frames_done`` chosen frames (a checkpoint's; their labels are in ``work``); returns the tracks report."""
    track_started = time.perf_counter()
    track_size = (survey.track_width, survey.track_height)
    recent: dict[int, np.ndarray] = {}  # the last ingest.track_backfill_frames frames at the tracking size
    for index, (frame_id, rgb) in enumerate(_chosen_frames(video, survey, "tracking people")):
        writer.frame(frame_id, resized(rgb, (survey.width, survey.height)))
        if index < frames_done - config.track_backfill_frames:
            continue  # tracked before the checkpoint, and too early to be looked at again
        tracked = resized(rgb, track_size)
        if index >= frames_done:
            _track_frame(tracker, frame_id, tracked, recent, work, config)
            if config.checkpoint_frames > 0 and (index + 1) % config.checkpoint_frames == 0:
                save_checkpoint(work / CHECKPOINT_FILE, tracker.tracks, index + 1, key)
        recent[frame_id] = tracked
        recent = {fid: image for fid, image in recent.items() if fid > frame_id - config.track_backfill_frames}
    track_seconds = time.perf_counter() - track_started
    people, dropped = _kept_people(tracker.tracks, survey, config,
                                   lambda frame_id: _read_labels(work, frame_id))
    if not people:
        raise GlimpseError(f"{video}: no person found in {len(survey.chosen)} frames (BlazePose saw nobody for "
                           f"{config.track_min_frames} frames or more at {config.track_min_height:g} of the frame's "
                           "height or taller: ingest.track_min_frames, track_min_height)"
                           + (f"; {dropped['upside_down']} track(s) stood upside down (a video turned over without "
                              "rotation metadata? ingest.track_max_upside_down)" if dropped["upside_down"] else "")
                           + "; Glimpse reconstructs people, so it needs a video with at least one person in view")
    additions: dict[int, list[tuple[int, np.ndarray]]] = {}
    if config.gap_masks and survey.plate is not None:
        people, additions = _masks_in_gaps(video, survey, config, people, work)
    labels_of = partial(_labels_with, work, additions)
    if config.keypoints_behind_again:
        people = _keypoints_behind(video, survey, tracker, people, labels_of)
    if survey.focal_35mm is not None:  # a moving camera's too: SfM keeps it (01_sfm.estimate_focal: its own)
        writer.input_cameras(survey.width, survey.height,
                             intrinsics_from_focal(survey.focal_35mm, survey.width, survey.height))
    for person in people:
        writer.keypoints2d(person.pid, np.array(person.frames), "coco17", person.keypoints, person.relative3d)
    _write_masks(writer, people, labels_of, survey, config)
    if config.preview:
        frames = ((fid, resized(rgb, (survey.width, survey.height)), _written_labels(writer, people, fid, survey))
                  for fid, rgb in _chosen_frames(video, survey, "drawing the preview"))
        write_mp4(writer.side_file(PREVIEW_FILE), preview_frames(frames, people, config.keypoint_min_confidence),
                  survey.fps)
    return tracks_report(people, dropped, _facts(video, survey, config, track_seconds, frames_done))


def _track_frame(tracker: Tracker, frame_id: int, image: np.ndarray, recent: dict[int, np.ndarray], work: Path,
                 config: IngestConfig) -> None:
    """Track one frame (``image`` at the tracking size), write its depth-ordered labels to ``work``, then look
    again at the ``recent`` frames (frame id -> image) that a track found again here had missed, and before the
    frame where a track started here (glimpse.ingest.backfill), their labels rewritten."""
    gaps = open_gaps(tracker.tracks, config.track_backfill_frames)
    known = len(tracker.tracks)
    observed = tracker.step(frame_id, image)
    labels = depth_ordered_labels(observed, image.shape[:2], config.mask_threshold, config.mask_body_radius,
                                  config.mask_depth_cue, config.mask_depth_frames)
    _write_labels(work, frame_id, labels)
    labels_of, write_labels = partial(_read_labels, work), partial(_write_labels, work)
    fill_gaps(tracker, gaps, observed, frame_id, recent, labels_of, write_labels)
    look_before_start(tracker, tracker.tracks[known:], frame_id, recent, labels_of, write_labels)


def _segment_seconds(survey: Survey) -> list[float]:
    """[first, last] scene frame's time in the video, seconds from its first frame."""
    ids = survey.chosen.values()
    return [min(ids) / survey.fps, max(ids) / survey.fps]


def _announce(video: Path, scene_dir: Path, survey: Survey, report: dict, config: IngestConfig) -> None:
    notes = []
    if (survey.width, survey.height) != (survey.info.width, survey.info.height):
        notes.append(f"downscaled {survey.info.width}x{survey.info.height} -> {survey.width}x{survey.height} "
                     f"(ingest.max_side {config.max_side})")
    if config.start_s > 0 or config.end_s is not None:
        first, last = _segment_seconds(survey)
        notes.append(f"kept {first:.2f}-{last:.2f} s of the video (ingest.start_s {config.start_s}, ingest.end_s "
                     f"{config.end_s}); frame ids {min(survey.chosen.values())}-{max(survey.chosen.values())} "
                     f"(id k at k / {survey.fps:g} s)")
    if survey.limited:
        notes.append(f"kept the first {config.max_frames} frames (ingest.max_frames)")
    if survey.truncated:
        notes.append(f"the file looks truncated: decoded {survey.decoded} of the {survey.info.frame_count} frames "
                     "its container lists; the scene holds those")
    print(f"ingested {video} -> {scene_dir}: {report['frames']} frames, {len(report['people'])} people, "
          f"camera {report['camera_motion']}")
    for note in notes:
        print(f"  note: {note}")
    print(report_table(report))
    print(f"  check the tracks before a run: {scene_dir / PREVIEW_FILE} and {scene_dir / REPORT_FILE}; correct "
          f"them with glimpse tracks {scene_dir} (--swap, --merge, --drop, --rename)")
