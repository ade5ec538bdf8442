"""Correcting who is who among a scene's people (``humans/<pid>/``), as a person does after looking at the ingest's
preview: merge two ids that are one person, exchange two people's data over some frames (an identity switch), drop
a person or some of their frames (a false find), rename one.

Per-frame data moves with its frames: every array of keypoints2d.npz, keypoints3d.npz and smpl.npz whose first
axis runs over the file's ``frame_ids``, and the masks. What belongs to the person stays with them: ``layout``,
``betas`` and ``reference/``. Data of one kind can only be joined where these agree (two keypoint layouts, two
body shapes cannot be one person's), and a frame can only be had once: merging two people seen in the same frame
is refused with the frames named.

:func:`edit_people` writes the changed people beside the scene, validates the scene with them in place, and puts
the old folders back if it does not pass; people it does not touch are not rewritten.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from glimpse.errors import GlimpseError, SceneError
from glimpse.io.images import frame_files, frame_name
from glimpse.scene._common import NAME_PATTERN

FRAME_FILES = ("keypoints2d.npz", "keypoints3d.npz", "smpl.npz")  # per-person .npz files with frame_ids
PERSON_KEYS = ("layout", "betas")  # arrays of those files that belong to the person, not to a frame
EDIT_STAGING_SUFFIX = ".people-edit"  # beside the scene folder: the new person folders, then the replaced ones


@dataclass
class PersonData:
    """One person's data, read whole: per file, its frame ids, per-frame arrays [T, ...] and person arrays; the
    mask files by frame id; the reference/ folder, if any."""

    files: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)  # file name -> key -> array
    masks: dict[int, Path] = field(default_factory=dict)
    reference: Path | None = None

    def frames(self) -> set[int]:
        """Every frame id this person has data in (any file, any mask)."""
        ids = {int(f) for arrays in self.files.values() for f in arrays["frame_ids"]}
        return ids | set(self.masks)


@dataclass(frozen=True)
class Edit:
    """One correction. ``kind``: merge (``people`` = (into, from): from's frames become into's), swap (two people's
    data exchanged), drop (one person, or their ``frames``), rename (``people`` = (old, new)). ``frames``:
    (first, end) frame ids, end excluded (None: to the last), that swap and drop act on (None: all)."""

    kind: str
    people: tuple[str, ...]
    frames: tuple[int, int | None] | None = None

    def describe(self) -> str:
        if self.frames is None:
            span = ""
        else:
            first, end = self.frames
            span = f" in frames {first}:{'' if end is None else end}"
        text = {"merge": "{1} merged into {0}", "swap": "{0} and {1} exchanged", "drop": "{0} dropped",
                "rename": "{0} renamed {1}"}[self.kind].format(*self.people)
        return text + span


def parse_frame_range(text: str) -> tuple[int, int | None]:
    """``A:B`` (frame ids, B excluded; either end may be empty: from the first, to the last) -> (A, B or None)."""
    first, sep, end = text.partition(":")
    try:
        span = (int(first) if first.strip() else 0, int(end) if end.strip() else None)
    except ValueError:
        span = None
    if not sep or span is None or span[0] < 0 or (span[1] is not None and span[1] <= span[0]):
        raise GlimpseError(f"--frames {text!r}: give A:B, frame ids from A to B (B excluded; A:, :B)")
    return span


def read_person(folder: Path) -> PersonData:
    """``humans/<pid>/`` -> its data (the scene is valid: glimpse validate)."""
    person = PersonData()
    for name in FRAME_FILES:
        if (folder / name).is_file():
            with np.load(folder / name, allow_pickle=False) as data:
                person.files[name] = {key: data[key] for key in data.files}
    if (folder / "masks").is_dir():
        person.masks = frame_files(folder / "masks")
    if (folder / "reference").is_dir():
        person.reference = folder / "reference"
    return person


def _per_frame(arrays: dict[str, np.ndarray], where: str) -> list[str]:
    """The keys of one file's arrays that run over its frame ids (first axis), refusing any other array that is
    not one of PERSON_KEYS."""
    count = len(arrays["frame_ids"])
    keys = []
    for key, array in arrays.items():
        if key == "frame_ids" or key in PERSON_KEYS:
            continue
        if array.ndim == 0 or array.shape[0] != count:
            raise GlimpseError(f"{where}: array {key!r} of shape {array.shape} neither runs over the {count} frame "
                               f"ids nor is one of {', '.join(PERSON_KEYS)}: cannot tell which frames it belongs to")
        keys.append(key)
    return keys


def select_frames(person: PersonData, keep: set[int], where: str) -> PersonData:
    """``person`` with only the frames in ``keep`` (a file left with no frame is dropped)."""
    out = PersonData(masks={f: path for f, path in person.masks.items() if f in keep}, reference=person.reference)
    for name, arrays in person.files.items():
        rows = np.isin(arrays["frame_ids"], list(keep))
        if rows.any():
            per_frame = {"frame_ids", *_per_frame(arrays, f"{where}/{name}")}
            out.files[name] = {key: array[rows] if key in per_frame else array for key, array in arrays.items()}
    return out


def join(a: PersonData, b: PersonData, where: str) -> PersonData:
    """One person from two with no frame in common: per file, the frames of both in order. The person arrays
    (layout, betas) must agree; ``b``'s reference/ is used only when ``a`` has none."""
    shared = sorted(a.frames() & b.frames())
    if shared:
        raise GlimpseError(f"{where}: both have data in {len(shared)} frame(s) ({_ids(shared)}); one person is in "
                           f"one place per frame: drop those frames from one of them first (--drop P --frames A:B)")
    out = PersonData(masks={**a.masks, **b.masks}, reference=a.reference or b.reference)
    for name in sorted(set(a.files) | set(b.files)):
        if name not in a.files or name not in b.files:
            out.files[name] = dict(a.files.get(name) or b.files[name])
            continue
        first, second = a.files[name], b.files[name]
        for key in PERSON_KEYS:
            if (key in first) != (key in second) or (key in first and not np.array_equal(first[key], second[key])):
                raise GlimpseError(f"{where}/{name}: {key!r} differs between the two; one person has one {key}")
        per_frame = _per_frame(first, f"{where}/{name}")
        if sorted(per_frame) != sorted(_per_frame(second, f"{where}/{name}")):
            raise GlimpseError(f"{where}/{name}: the two hold different arrays ({', '.join(sorted(first))} against "
                               f"{', '.join(sorted(second))})")
        ids = np.concatenate([first["frame_ids"], second["frame_ids"]])
        order = np.argsort(ids, kind="stable")
        joined = {key: np.concatenate([first[key], second[key]])[order] for key in ["frame_ids", *per_frame]}
        out.files[name] = {**{k: first[k] for k in PERSON_KEYS if k in first}, **joined}
    return out


def apply_edit(people: dict[str, PersonData], edit: Edit) -> dict[str, PersonData | None]:
    """The people ``edit`` changes -> their new data (None: the person is removed). Pure: nothing is written."""
    def person(pid: str) -> PersonData:
        if pid not in people:
            raise GlimpseError(f"humans/{pid}: no such person (the scene has {', '.join(sorted(people)) or 'none'})")
        return people[pid]

    def where(*pids: str) -> str:
        return " and ".join(f"humans/{pid}" for pid in pids)

    if edit.kind == "merge":
        into, source = edit.people
        if into == source:
            raise GlimpseError(f"--merge {into}={source}: a person cannot be merged into themselves")
        return {into: join(person(into), person(source), where(into, source)), source: None}
    if edit.kind == "rename":
        old, new = edit.people
        if not NAME_PATTERN.fullmatch(new) or new == "union":
            raise GlimpseError(f"--rename {old}={new}: a person id is letters, digits, _ or - (not 'union')")
        if new in people:
            raise GlimpseError(f"--rename {old}={new}: humans/{new} exists (merge them with --merge {new}={old})")
        return {new: person(old), old: None}
    span = edit.frames

    def inside(frames: set[int]) -> set[int]:
        return frames if span is None else {f for f in frames if span[0] <= f and (span[1] is None or f < span[1])}

    if edit.kind == "drop":
        (pid,) = edit.people
        data = person(pid)
        gone = inside(data.frames())
        if not gone:
            raise GlimpseError(f"{edit.describe()}: {pid} has no data in those frames")
        rest = data.frames() - gone
        return {pid: select_frames(data, rest, where(pid)) if rest else None}
    if edit.kind == "swap":
        a, b = edit.people
        if a == b:
            raise GlimpseError(f"--swap {a},{b}: two different people are exchanged")
        first, second = person(a), person(b)
        moved_a, moved_b = inside(first.frames()), inside(second.frames())
        if not moved_a and not moved_b:
            raise GlimpseError(f"--swap {a},{b}: neither has data in the frames given")
        keep_a = select_frames(first, first.frames() - moved_a, where(a))
        keep_b = select_frames(second, second.frames() - moved_b, where(b))
        new_a = join(keep_a, select_frames(second, moved_b, where(b)), where(a, b))
        new_b = join(keep_b, select_frames(first, moved_a, where(a)), where(b, a))
        return {a: new_a if new_a.frames() else None, b: new_b if new_b.frames() else None}
    raise GlimpseError(f"unknown edit {edit.kind!r}")


def write_person(person: PersonData, folder: Path) -> None:
    """A person's data as ``humans/<pid>/`` at ``folder`` (created; masks and reference copied)."""
    folder.mkdir(parents=True)
    for name, arrays in person.files.items():
        np.savez(folder / name, **arrays)
    if person.masks:
        (folder / "masks").mkdir()
        for frame_id, path in sorted(person.masks.items()):
            shutil.copy2(path, folder / "masks" / (frame_name(frame_id) + path.suffix))
    if person.reference is not None:
        shutil.copytree(person.reference, folder / "reference")


def edit_people(scene: Path, edit: Edit) -> list[str]:
    """Apply ``edit`` to the scene folder ``scene`` in place; returns the ids of the people it changed. The new
    person folders are written beside the scene and swapped in; the scene is then validated and, if it fails,
    the old folders are put back (SceneError). Nothing else in the scene changes."""
    from glimpse.scene.validate import validate_scene

    scene = Path(scene)
    humans = scene / "humans"
    folders = sorted(f for f in humans.iterdir() if f.is_dir()) if humans.is_dir() else []
    people = {folder.name: read_person(folder) for folder in folders}
    changed = apply_edit(people, edit)
    staging = scene.with_name(scene.name + EDIT_STAGING_SUFFIX)
    shutil.rmtree(staging, ignore_errors=True)
    (staging / "new").mkdir(parents=True)
    (staging / "old").mkdir()
    for pid, data in changed.items():
        if data is not None:
            write_person(data, staging / "new" / pid)
    moved_out: list[str] = []  # whose old folder now lies in staging/old
    placed: list[str] = []  # whose new folder now lies in humans/
    try:
        for pid in changed:
            if (humans / pid).exists():
                (humans / pid).rename(staging / "old" / pid)
                moved_out.append(pid)
        for pid, data in changed.items():
            if data is not None:
                (staging / "new" / pid).rename(humans / pid)
                placed.append(pid)
        violations = validate_scene(scene)
        if violations:
            raise SceneError(str(scene), violations)
    except BaseException:
        for pid in placed:
            shutil.rmtree(humans / pid)
        for pid in moved_out:
            (staging / "old" / pid).rename(humans / pid)
        shutil.rmtree(staging, ignore_errors=True)
        raise
    shutil.rmtree(staging)
    return sorted(changed)


def _ids(frames: list[int]) -> str:
    return ", ".join(str(f) for f in frames[:8]) + (", ..." if len(frames) > 8 else "")
