"""What a person checks before spending an hour on optimisation: a preview video of the tracks (id, box,
skeleton and mask outline over each frame) and a tracks report (frames per person, mean confidence,
suspected identity switches)."""

from __future__ import annotations

import colorsys
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from glimpse.io.images import read_mask

REPORT_FORMAT = "glimpse-tracks/1"
PREVIEW_FILE = "ingest/preview.mp4"  # in the scene folder (the scene format ignores ingest/)
REPORT_FILE = "ingest/tracks.json"
# COCO-17 limbs drawn in the preview.
COCO17_LIMBS = ((5, 7), (7, 9), (6, 8), (8, 10), (5, 6), (5, 11), (6, 12), (11, 12), (11, 13), (13, 15),
                (12, 14), (14, 16), (0, 5), (0, 6))
GOLDEN_RATIO = 0.618033988749895  # hue step between successive people's colours


@dataclass(frozen=True)
class PersonTrack:
    """One kept person, as the scene names them."""

    pid: str
    label: int  # value in the label maps
    frames: list[int]
    keypoints: np.ndarray  # [T, 17, 3]
    relative3d: np.ndarray  # [T, 17, 4] metres from the mid hip, image axes, confidence (Track.relative3d)
    boxes: np.ndarray  # [T, 4]
    reidentified: list[tuple[int, float]]
    jumps: list[int]
    sides_exchanged: list[int] = field(default_factory=list)  # frame ids whose left/right labels were exchanged
    border_squeezed: list[int] = field(default_factory=list)  # frame ids whose keypoints were not written
    legs_exchanged: list[int] = field(default_factory=list)  # frame ids whose knees and ankles were exchanged
    looked_again: list[int] = field(default_factory=list)  # frame ids the track had missed, filled afterwards
    masks_from_foreground: list[int] = field(default_factory=list)  # frame ids with a mask and no keypoints
    keypoints_behind: list[int] = field(default_factory=list)  # frame ids whose keypoints were looked for again
    #                                                            behind someone (glimpse.ingest.behind)


def person_colour(k: int) -> tuple[int, int, int]:
    r, g, b = colorsys.hsv_to_rgb((k * GOLDEN_RATIO) % 1.0, 0.85, 1.0)
    return int(r * 255), int(g * 255), int(b * 255)


def draw_frame(image: np.ndarray, labels: np.ndarray, people: list[PersonTrack], frame_id: int,
               min_confidence: float) -> np.ndarray:
    """One preview frame: every person's mask outline, box, skeleton and id over ``image`` [H, W, 3] uint8."""
    out = image.copy()
    thickness = max(1, round(max(image.shape[:2]) / 400))
    for k, person in enumerate(people):
        if frame_id not in person.frames:  # nobody found: the person has no pixels in ``labels`` either
            continue
        colour = person_colour(k)
        mask = (labels == person.label).astype(np.uint8)
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        cv2.drawContours(out, contours, -1, colour, thickness)
        t = person.frames.index(frame_id)
        x0, y0, x1, y1 = np.round(person.boxes[t]).astype(int)
        cv2.rectangle(out, (x0, y0), (x1, y1), colour, thickness)
        keypoints = person.keypoints[t]
        for a, b in COCO17_LIMBS:
            if keypoints[a, 2] >= min_confidence and keypoints[b, 2] >= min_confidence:
                cv2.line(out, tuple(np.round(keypoints[a, :2]).astype(int)), tuple(np.round(keypoints[b, :2]).astype(int)),
                         colour, thickness, cv2.LINE_AA)
        for x, y, c in keypoints:
            if c >= min_confidence:
                cv2.circle(out, (round(x), round(y)), thickness + 1, colour, -1, cv2.LINE_AA)
        scale = max(image.shape[:2]) / 800
        cv2.putText(out, person.pid, (x0, max(y0 - 4, 12)), cv2.FONT_HERSHEY_SIMPLEX, max(scale, 0.4), colour,
                    thickness, cv2.LINE_AA)
    return out


def labels_from_masks(height: int, width: int, masks: list[tuple[int, Path]]) -> np.ndarray:
    """[height, width] uint16 label map of one frame from its people's (label, mask file) pairs; 0 = nobody."""
    labels = np.zeros((height, width), np.uint16)
    for label, mask_file in masks:
        labels[read_mask(mask_file)] = label
    return labels


def preview_frames(frames: Iterator[tuple[int, np.ndarray, np.ndarray]], people: list[PersonTrack],
                   min_confidence: float) -> Iterator[np.ndarray]:
    for frame_id, image, labels in frames:
        yield draw_frame(image, labels, people, frame_id, min_confidence)


def tracks_report(people: list[PersonTrack], dropped: dict, facts: dict) -> dict:
    """The tracks report (tracks.json): the video's facts, then per person what was found, and how many tracks
    were dropped (``dropped``: {"short": n, "small": n})."""
    persons = {}
    for person in people:
        confidence = person.keypoints[..., 2]
        persons[person.pid] = {
            "frames": len(person.frames), "first_frame": person.frames[0], "last_frame": person.frames[-1],
            "gaps": int(person.frames[-1] - person.frames[0] + 1 - len(person.frames)),
            "mean_confidence": float(confidence[confidence > 0].mean()) if (confidence > 0).any() else 0.0,
            "visible_keypoints": float((confidence > 0).mean()),
            "sides_exchanged": person.sides_exchanged,
            "border_squeezed": person.border_squeezed,
            "legs_exchanged": person.legs_exchanged,
            "looked_again": person.looked_again,
            "masks_from_foreground": person.masks_from_foreground,
            "keypoints_behind": person.keypoints_behind,
            "suspected_switches": [{"frame": f, "why": "re-identified after a gap", "appearance_distance": round(d, 3)}
                                   for f, d in person.reidentified]
                                  + [{"frame": f, "why": "the box jumped"} for f in person.jumps],
        }
    return {"format": REPORT_FORMAT, **facts, "people": persons, "dropped_short_tracks": dropped["short"],
            "dropped_small_tracks": dropped["small"], "dropped_upside_down_tracks": dropped["upside_down"]}


def report_table(report: dict) -> str:
    """The report as a text table for the terminal."""
    lines = [f"{'person':8} {'frames':>7} {'first':>6} {'last':>6} {'gaps':>5} {'conf':>5} {'switches?':>9}"]
    for pid, p in report["people"].items():
        lines.append(f"{pid:8} {p['frames']:7d} {p['first_frame']:6d} {p['last_frame']:6d} {p['gaps']:5d} "
                     f"{p['mean_confidence']:5.2f} {len(p['suspected_switches']):9d}")
    return "\n".join(lines)
