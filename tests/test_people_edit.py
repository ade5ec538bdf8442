"""Correcting a scene's people (glimpse.scene.people_edit, `glimpse tracks`): merging two ids, exchanging two people's
data over some frames, dropping a person or some of their frames, renaming; refusals that name the files and frames;
the scene left as it was when the result would not be valid; the ingest's preview drawn again."""

from __future__ import annotations

import json
import re
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from glimpse.cli import main as cli_main
from glimpse.errors import EXIT_BAD_INPUT, GlimpseError, SceneError
from glimpse.io.images import read_mask
from glimpse.scene import SceneWriter, load_scene
from glimpse.scene.people_edit import Edit, apply_edit, edit_people, parse_frame_range, read_person

WIDTH, HEIGHT, FRAMES = 48, 32, 6


def _keypoints(pid_value: float, frames: list[int]) -> np.ndarray:
    """[T, 17, 3]: x = the person's value, y = the frame id, confidence 1 (which person and frame a row came from)."""
    out = np.ones((len(frames), 17, 3))
    out[..., 0] = pid_value
    out[..., 1] = np.array(frames, float)[:, None]
    return out


def _mask(column: int) -> np.ndarray:
    mask = np.zeros((HEIGHT, WIDTH), bool)
    mask[4:28, column:column + 6] = True
    return mask


def _scene(root: Path, people: dict[str, tuple[list[int], float, int]], preview: bool = False) -> Path:
    """A small scene: per pid (frame ids, keypoint x, mask column); with ``preview``, an ingest's preview and
    tracks report beside it."""
    writer = SceneWriter(root, "people", fps=10, camera_motion="static")
    for f in range(FRAMES):
        writer.frame(f, np.full((HEIGHT, WIDTH, 3), 40 * f, np.uint8))
    for pid, (frames, value, column) in people.items():
        writer.keypoints2d(pid, np.array(frames), "coco17", _keypoints(value, frames))
        for f in frames:
            writer.person_mask(pid, f, _mask(column))
    if preview:
        iio.imwrite(writer.side_file("ingest/preview.mp4"), np.zeros((FRAMES, HEIGHT, WIDTH, 3), np.uint8), fps=10)
        suspicion = {"p0": {"suspected_switches": [{"frame": 2, "why": "the box jumped"}]}}
        writer.side_file("ingest/tracks.json").write_text(json.dumps({"format": "glimpse-tracks/1",
                                                                      "people": suspicion}))
    return writer.finish()


def _rows(scene: Path, pid: str) -> dict[int, float]:
    """Frame id -> the keypoint x (which person the row came from)."""
    with np.load(scene / "humans" / pid / "keypoints2d.npz") as data:
        assert list(data["frame_ids"]) == sorted(data["frame_ids"])
        assert all(data["keypoints"][k, 0, 1] == f for k, f in enumerate(data["frame_ids"]))
        return {int(f): float(k[0, 0]) for f, k in zip(data["frame_ids"], data["keypoints"])}


def _mask_columns(scene: Path, pid: str) -> dict[int, int]:
    masks = load_scene(scene).humans[pid].masks
    return {f: int(np.nonzero(read_mask(path))[1].min()) for f, path in masks.items()}


def test_a_merge_joins_two_ids_frames_in_order_and_removes_the_second(tmp_path) -> None:
    scene = _scene(tmp_path / "s", {"p0": ([0, 1, 2], 10.0, 2), "p2": ([4, 5], 20.0, 30)})
    assert edit_people(scene, Edit("merge", ("p0", "p2"))) == ["p0", "p2"]
    assert _rows(scene, "p0") == {0: 10.0, 1: 10.0, 2: 10.0, 4: 20.0, 5: 20.0}
    assert _mask_columns(scene, "p0") == {0: 2, 1: 2, 2: 2, 4: 30, 5: 30}
    assert not (scene / "humans" / "p2").exists()
    assert not scene.with_name("s.people-edit").exists()


def test_a_swap_exchanges_two_peoples_data_in_the_frames_given_only(tmp_path) -> None:
    scene = _scene(tmp_path / "s", {"p0": ([0, 1, 2, 3, 4], 10.0, 2), "p1": ([1, 2, 3, 4, 5], 20.0, 30)})
    edit_people(scene, Edit("swap", ("p0", "p1"), parse_frame_range("3:")))
    assert _rows(scene, "p0") == {0: 10.0, 1: 10.0, 2: 10.0, 3: 20.0, 4: 20.0, 5: 20.0}
    assert _rows(scene, "p1") == {1: 20.0, 2: 20.0, 3: 10.0, 4: 10.0}
    assert _mask_columns(scene, "p1") == {1: 30, 2: 30, 3: 2, 4: 2}


def test_dropping_frames_keeps_the_rest_and_dropping_all_removes_the_person(tmp_path) -> None:
    scene = _scene(tmp_path / "s", {"p0": ([0, 1, 2, 3], 10.0, 2), "p1": ([0, 1], 20.0, 30)})
    edit_people(scene, Edit("drop", ("p0",), parse_frame_range("1:3")))
    assert _rows(scene, "p0") == {0: 10.0, 3: 10.0}
    assert sorted(_mask_columns(scene, "p0")) == [0, 3]
    edit_people(scene, Edit("drop", ("p1",)))
    assert sorted(load_scene(scene).humans) == ["p0"]


def test_a_rename_moves_the_folder_and_refuses_a_taken_or_invalid_id(tmp_path) -> None:
    scene = _scene(tmp_path / "s", {"p0": ([0, 1], 10.0, 2), "p1": ([2], 20.0, 30)})
    edit_people(scene, Edit("rename", ("p0", "alice")))
    assert sorted(load_scene(scene).humans) == ["alice", "p1"]
    with pytest.raises(GlimpseError, match="humans/p1 exists"):
        edit_people(scene, Edit("rename", ("alice", "p1")))
    with pytest.raises(GlimpseError, match="letters, digits"):
        edit_people(scene, Edit("rename", ("alice", "a/b")))


def test_refusals_name_the_shared_frames_the_layouts_and_the_people(tmp_path) -> None:
    scene = _scene(tmp_path / "s", {"p0": ([0, 1, 2], 10.0, 2), "p1": ([2, 3], 20.0, 30), "p2": ([4, 5], 30.0, 20)})
    people = {p.name: read_person(p) for p in (scene / "humans").iterdir()}
    with pytest.raises(GlimpseError, match=r"humans/p0 and humans/p1: both have data in 1 frame\(s\) \(2\)"):
        apply_edit(people, Edit("merge", ("p0", "p1")))
    people["p2"].files["keypoints2d.npz"]["layout"] = np.array("openpose25")
    with pytest.raises(GlimpseError, match="humans/p0 and humans/p2/keypoints2d.npz: 'layout' differs"):
        apply_edit(people, Edit("merge", ("p0", "p2")))
    with pytest.raises(GlimpseError, match="humans/p7: no such person"):
        apply_edit(people, Edit("drop", ("p7",)))
    with pytest.raises(GlimpseError, match="no data in those frames"):
        apply_edit(people, Edit("drop", ("p1",), (4, None)))
    for text in ("3", "5:2", "a:b", "-1:"):
        with pytest.raises(GlimpseError, match="--frames"):
            parse_frame_range(text)


def test_a_result_that_is_not_a_valid_scene_leaves_the_people_as_they_were(tmp_path, monkeypatch) -> None:
    scene = _scene(tmp_path / "s", {"p0": ([0, 1], 10.0, 2), "p1": ([2, 3], 20.0, 30)})
    before = {p.relative_to(scene): p.read_bytes() for p in sorted((scene / "humans").rglob("*")) if p.is_file()}
    import glimpse.scene.validate as validate

    monkeypatch.setattr(validate, "validate_scene", lambda root: ["a violation"])
    with pytest.raises(SceneError):
        edit_people(scene, Edit("merge", ("p0", "p1")))
    after = {p.relative_to(scene): p.read_bytes() for p in sorted((scene / "humans").rglob("*")) if p.is_file()}
    assert after == before
    assert not scene.with_name("s.people-edit").exists()


def test_the_command_records_the_edit_draws_the_preview_again_and_prints_the_people(tmp_path, capsys) -> None:
    scene = _scene(tmp_path / "s", {"p0": ([0, 1, 2, 3], 10.0, 2), "p1": ([0, 1, 2, 3], 20.0, 30)}, preview=True)
    assert cli_main(["tracks", str(scene), "--swap", "p0,p1", "--frames", "2:"]) == 0
    printed = capsys.readouterr().out
    assert "p0 and p1 exchanged in frames 2:" in printed and "preview drawn again" in printed
    assert re.search(r"^p0 +4 +0 +3 +0 +4 +4 +1.00$", printed, re.MULTILINE)  # frames, first, last, gaps, kpts, masks
    assert "(its ids; 1 correction(s) made since, which may have renamed them)" in printed
    assert "  p0 frame 2: the box jumped" in printed
    assert json.loads((scene / "ingest/tracks.json").read_text())["edits"] == ["p0 and p1 exchanged in frames 2:"]
    preview = iio.imread(scene / "ingest/preview.mp4")
    assert len(preview) == FRAMES and preview[0].shape == (HEIGHT, WIDTH, 3)
    assert preview[0].max() > 100  # the people's outlines and boxes, drawn over a dark frame
    assert cli_main(["tracks", str(scene), "--frames", "2:"]) == EXIT_BAD_INPUT
    assert "--frames goes with --swap or --drop" in capsys.readouterr().err
    assert cli_main(["tracks", str(scene), "--merge", "p0"]) == EXIT_BAD_INPUT
    assert "give INTO=FROM" in capsys.readouterr().err


def test_body_parameters_join_per_frame_only_under_one_body_shape(tmp_path) -> None:
    writer = SceneWriter(tmp_path / "s", "bodies", fps=10, camera_motion="static")
    for f in range(4):
        writer.frame(f, np.zeros((HEIGHT, WIDTH, 3), np.uint8))
    for pid, frames, beta in (("p0", [0, 1], 0.0), ("p1", [2, 3], 0.0), ("p2", [2, 3], 0.5)):
        count = len(frames)
        writer.smpl(pid, np.array(frames), np.full(10, beta), np.zeros((count, 3)), np.zeros((count, 69)),
                    np.array(frames, float)[:, None].repeat(3, 1))
    scene = writer.finish()
    people = {p.name: read_person(p) for p in (scene / "humans").iterdir()}
    merged = apply_edit(people, Edit("merge", ("p0", "p1")))["p0"].files["smpl.npz"]
    assert list(merged["frame_ids"]) == [0, 1, 2, 3] and merged["betas"].shape == (10,)
    assert np.array_equal(merged["transl"][:, 0], [0, 1, 2, 3])
    with pytest.raises(GlimpseError, match="humans/p0 and humans/p2/smpl.npz: 'betas' differs"):
        apply_edit(people, Edit("merge", ("p0", "p2")))
