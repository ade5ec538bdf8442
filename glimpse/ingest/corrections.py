"""After a person corrects an ingested scene's people (``glimpse tracks``, glimpse.scene.people_edit): the tracks
report records the correction and the preview is drawn again from the scene as it now is, so that what a person
checks before a run shows the ids the run will use.

The report keeps what the ingest found (its per-person lists describe the tracker's ids) and gains ``edits``, the
corrections in the order they were made. The preview is drawn from the scene's own files: its frames, each
person's masks and COCO-17 keypoints (a person without keypoints: outline and box only; the box is that of the
mask, else of the keypoints).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from glimpse.ingest.gap_masks import mask_box
from glimpse.ingest.report import PREVIEW_FILE, REPORT_FILE, PersonTrack, labels_from_masks, preview_frames
from glimpse.io.images import read_mask, read_rgb
from glimpse.io.json_file import write_json
from glimpse.io.staging import staged_file
from glimpse.io.video import write_mp4
from glimpse.scene import Scene, load_scene
from glimpse.scene.model import KEYPOINT_LAYOUTS
from glimpse.scene.people_edit import Edit, edit_people, read_person

COCO17_JOINTS = KEYPOINT_LAYOUTS["coco17"]


def record_edit(scene_dir: Path, description: str) -> bool:
    """Append ``description`` to the tracks report's ``edits``; False when the scene has no tracks report."""
    path = Path(scene_dir) / REPORT_FILE
    if not path.is_file():
        return False
    report = json.loads(path.read_text())
    report["edits"] = [*report.get("edits", []), description]
    with staged_file(path) as staged:
        write_json(staged, report)
    return True


def scene_people(scene: Scene) -> list[PersonTrack]:
    """A loaded scene's people as the preview draws them: frames with a mask or keypoints, COCO-17 keypoints
    (confidence 0 where there are none), boxes."""
    people = []
    for label, (pid, human) in enumerate(sorted(scene.humans.items()), start=1):
        points: dict[int, np.ndarray] = {}
        if human.keypoints2d is not None:
            with np.load(human.keypoints2d, allow_pickle=False) as data:
                if str(data["layout"]) == "coco17":
                    points = {int(f): k for f, k in zip(data["frame_ids"], data["keypoints"])}
        frames = sorted(set(points) | set(human.masks))
        if not frames:
            continue
        keypoints = np.stack([points.get(f, np.zeros((COCO17_JOINTS, 3))) for f in frames])
        boxes = np.stack([_box(human.masks.get(f), keypoints[k]) for k, f in enumerate(frames)])
        people.append(PersonTrack(pid, label, frames, keypoints, np.zeros((len(frames), COCO17_JOINTS, 4)), boxes,
                                  reidentified=[], jumps=[]))
    return people


def redraw_preview(scene_dir: Path, min_confidence: float) -> Path | None:
    """Draw ``ingest/preview.mp4`` again from the scene (keypoints below ``min_confidence`` not drawn); None (and
    nothing written) when the scene has no preview to replace."""
    scene_dir = Path(scene_dir)
    path = scene_dir / PREVIEW_FILE
    scene = load_scene(scene_dir)
    if not path.is_file() or not scene.frame_paths:
        return None
    people = scene_people(scene)
    masks = {pid: human.masks for pid, human in scene.humans.items()}

    def frames():
        for frame_id in scene.frame_ids:
            here = [(person.label, masks[person.pid][frame_id]) for person in people if frame_id in masks[person.pid]]
            yield frame_id, read_rgb(scene.frame_paths[frame_id]), labels_from_masks(scene.height, scene.width, here)

    write_mp4(path, preview_frames(frames(), people, min_confidence), scene.fps)  # written beside it, then renamed
    return path


def _box(mask_file: Path | None, keypoints: np.ndarray) -> np.ndarray:
    """(4,) x0, y0, x1, y1: the box of a mask, else of the keypoints with a confidence (zeros: neither)."""
    if mask_file is not None:
        mask = read_mask(mask_file)
        if mask.any():
            return mask_box(mask)
    seen = keypoints[keypoints[:, 2] > 0, :2]
    return np.concatenate([seen.min(0), seen.max(0)]) if len(seen) else np.zeros(4)


def people_table(scene_dir: Path) -> str:
    """The scene's people as a text table: frames with any data (keypoints, body, mask), first and last, gaps,
    frames with 2D keypoints and with a mask, mean 2D keypoint confidence."""
    lines = [f"{'person':8} {'frames':>7} {'first':>6} {'last':>6} {'gaps':>5} {'kpts':>5} {'masks':>6} {'conf':>5}"]
    for pid in sorted(load_scene(scene_dir).humans):
        data = read_person(Path(scene_dir) / "humans" / pid)
        frames = sorted(data.frames())
        if not frames:
            continue
        confidence = data.files.get("keypoints2d.npz", {}).get("keypoints", np.zeros((0, 1, 3)))[..., 2]
        mean = float(confidence[confidence > 0].mean()) if (confidence > 0).any() else 0.0
        lines.append(f"{pid:8} {len(frames):7d} {frames[0]:6d} {frames[-1]:6d} "
                     f"{frames[-1] - frames[0] + 1 - len(frames):5d} {int((confidence > 0).any(1).sum()):5d} "
                     f"{len(data.masks):6d} {mean:5.2f}")
    return "\n".join(lines)


def suspected_switches(scene_dir: Path) -> list[str]:
    """The identity switches the ingest suspected (its tracks report), one line each, under the ids it gave; the
    first line says how many corrections were made since (their ids may differ). Empty without a report or a
    suspicion."""
    path = Path(scene_dir) / REPORT_FILE
    if not path.is_file():
        return []
    report = json.loads(path.read_text())
    lines = [f"  {pid} frame {s['frame']}: {s['why']}" for pid, person in report.get("people", {}).items()
             for s in person.get("suspected_switches", [])]
    if not lines:
        return []
    edits = len(report.get("edits", []))
    since = f"; {edits} correction(s) made since, which may have renamed them" if edits else ""
    return [f"identity switches the ingest suspected (its ids{since}):", *lines]


def correct(scene_dir: Path, edit: Edit, min_confidence: float) -> list[str]:
    """Apply ``edit`` to the scene's people (glimpse.scene.people_edit.edit_people), record it in the tracks
    report and draw the preview again (when the scene has them); returns what was done, one line each."""
    changed = edit_people(scene_dir, edit)
    done = [f"{edit.describe()} (changed: {', '.join(changed)})"]
    if record_edit(scene_dir, edit.describe()):
        done.append(f"recorded in {Path(scene_dir) / REPORT_FILE}")
    preview = redraw_preview(scene_dir, min_confidence)
    if preview is not None:
        done.append(f"preview drawn again: {preview}")
    return done
