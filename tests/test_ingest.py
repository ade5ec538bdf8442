"""`glimpse ingest VIDEO SCENE_DIR`: videos in (rotated, variable-rate, broken, empty, oversized, without
people) and, on a rendered fixture scene with known people, a valid scene out with every person found and
tracked under one id (BlazePose's real models, from `make models`)."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from glimpse.errors import GlimpseError
from glimpse.fixtures.scenes import make_scene
from glimpse.ingest.config import load_ingest_config
from glimpse.ingest.stage import PREVIEW_FILE, REPORT_FILE, blazepose_folder, ingest
from glimpse.ingest.survey import survey_video
from glimpse.io.images import read_rgb
from glimpse.io.video import probe_video, read_mp4, write_mp4
from glimpse.scene import load_scene, read_keypoints2d, validate_scene

CONFIG = load_ingest_config()
MODELS_MISSING = not (blazepose_folder(CONFIG) / "pose_landmark_full.tflite").is_file()
needs_models = pytest.mark.skipif(MODELS_MISSING, reason="BlazePose models missing: run `make models`")


def _ffmpeg() -> str:
    import imageio_ffmpeg

    return imageio_ffmpeg.get_ffmpeg_exe()


def _pattern_video(path: Path, frames: int = 10, size: tuple[int, int] = (64, 48), fps: float = 10.0) -> Path:
    """A video whose left half is red and right half blue (so an orientation change shows)."""
    width, height = size
    image = np.zeros((height, width, 3), np.uint8)
    image[:, : width // 2] = [220, 20, 20]
    image[:, width // 2:] = [20, 20, 220]
    write_mp4(path, (image for _ in range(frames)), fps)
    return path


def test_rotated_video_is_read_upright(tmp_path: Path) -> None:
    plain = _pattern_video(tmp_path / "plain.mp4")
    rotated = tmp_path / "rotated.mp4"
    subprocess.run([_ffmpeg(), "-y", "-loglevel", "error", "-display_rotation", "90", "-i", str(plain), "-c", "copy",
                    str(rotated)], check=True)
    info = probe_video(rotated)
    assert (info.width, info.height) == (48, 64) and info.rotation_deg in (90.0, 270.0)
    survey = survey_video(rotated, CONFIG)
    assert (survey.width, survey.height) == (48, 64)


def test_variable_frame_rate_becomes_a_constant_rate_scene(tmp_path: Path) -> None:
    source = _pattern_video(tmp_path / "source.mp4", frames=20)
    vfr = tmp_path / "vfr.mp4"
    # frames 0-9 every 0.1 s, then frames 10-19 every 0.3 s: 3.7 s in all
    subprocess.run([_ffmpeg(), "-y", "-loglevel", "error", "-i", str(source), "-vf",
                    "setpts='if(lt(N,10),N*0.1,1.0+(N-10)*0.3)/TB'", "-fps_mode", "vfr", "-c:v", "libx264",
                    "-pix_fmt", "yuv420p", str(vfr)], check=True)
    from dataclasses import replace

    survey = survey_video(vfr, replace(CONFIG, fps=10.0))
    assert survey.decoded == 20
    ids = sorted(survey.chosen.values())
    assert len(survey.chosen) == 20 and ids == list(range(10)) + [10, 13, 16, 19, 22, 25, 28, 31, 34, 37]


@pytest.mark.parametrize("content", [b"", b"not a video at all\n" * 50], ids=["empty-file", "text-file"])
def test_unreadable_files_get_one_clear_error(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "clip.mp4"
    path.write_bytes(content)
    with pytest.raises(GlimpseError, match=r"clip\.mp4: not a readable video"):
        ingest(path, tmp_path / "scene", CONFIG)
    assert not (tmp_path / "scene").exists()


def test_truncated_video_is_refused_or_reported(tmp_path: Path) -> None:
    whole = _pattern_video(tmp_path / "whole.mp4", frames=30)
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    try:
        survey = survey_video(cut, CONFIG)
    except GlimpseError as error:
        assert "cut.mp4" in str(error)
    else:
        assert survey.truncated and survey.decoded < 30


def test_a_part_of_the_video_keeps_the_whole_videos_frame_ids(tmp_path: Path) -> None:
    """ingest.start_s / end_s: scene frame id k is the frame on screen at k / fps whatever the part; a frame limit
    counts from the start; a part past the end, or ending before it starts, is refused naming the parameter."""
    from dataclasses import replace

    video = _pattern_video(tmp_path / "clip.mp4", frames=30)  # 3 s at 10 fps
    survey = survey_video(video, replace(CONFIG, start_s=1.0, end_s=2.0))
    assert survey.chosen == {k: k for k in range(10, 21)} and survey.decoded == 22  # stops one frame after 2.0 s
    assert not survey.limited and not survey.truncated
    survey = survey_video(video, replace(CONFIG, start_s=1.0, max_frames=5))
    assert survey.chosen == {k: k for k in range(10, 15)} and survey.limited
    survey = survey_video(video, replace(CONFIG, start_s=2.55, fps=5.0))  # the grid of 5 fps: ids 13 and 14
    assert survey.chosen == {26: 13, 28: 14} and not survey.limited and not survey.truncated
    for start, end, message in ((5.0, None, r"ingest\.start_s \(5\.0 s\) is past the video's end \(2\.90 s\)"),
                                (1.0, 1.0, r"ingest\.end_s \(1\.0 s\) must come after ingest\.start_s"),
                                (-1.0, None, r"ingest\.start_s must be 0 or more seconds")):
        with pytest.raises(GlimpseError, match=r"clip\.mp4: " + message):
            survey_video(video, replace(CONFIG, start_s=start, end_s=end))


def test_missing_video(tmp_path: Path) -> None:
    with pytest.raises(GlimpseError, match="no such video file"):
        ingest(tmp_path / "nothing.mp4", tmp_path / "scene", CONFIG)


def test_a_scene_path_that_is_a_file_is_refused_before_the_video_is_read(tmp_path: Path) -> None:
    (tmp_path / "scene").write_text("not a scene")
    with pytest.raises(GlimpseError, match="scene: exists and is not a folder"):
        ingest(tmp_path / "nothing.mp4", tmp_path / "scene", CONFIG)  # no video either: the scene path comes first


@needs_models
def test_video_without_people_keeps_a_previous_scene(tmp_path: Path) -> None:
    video = _pattern_video(tmp_path / "empty_room.mp4", frames=12, size=(160, 120))
    scene = tmp_path / "scene"
    scene.mkdir()
    (scene / "keep.txt").write_text("an earlier scene")
    with pytest.raises(GlimpseError, match="no person found"):
        ingest(video, scene, CONFIG)
    assert (scene / "keep.txt").read_text() == "an earlier scene"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty_room.mp4", "scene"]  # no staging left behind


# --- a rendered scene with known people ------------------------------------------------------------------------

@pytest.fixture(scope="module")
def demo_video(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The demo fixture (two people crossing, one cut by the frame border) at 480x360, as a video."""
    root = tmp_path_factory.mktemp("ingest")
    fixture = make_scene("demo", root / "demo", "medium", seed=3)
    scene = load_scene(fixture)
    video = write_mp4(root / "demo.mp4", (read_rgb(scene.frame_paths[f]) for f in scene.frame_ids), scene.fps)
    assert video == len(scene.frame_ids)
    return fixture, root / "demo.mp4"


@pytest.fixture(scope="module")
def ingested(demo_video: tuple[Path, Path]) -> tuple[Path, dict]:
    fixture, video = demo_video
    scene = fixture.with_name("ingested")
    report = ingest(video, scene, CONFIG)
    return scene, report


@needs_models
def test_ingest_writes_a_valid_scene_with_both_people(demo_video, ingested) -> None:
    fixture, _ = demo_video
    scene_dir, report = ingested
    assert validate_scene(scene_dir) == []
    scene = load_scene(scene_dir)
    truth = load_scene(fixture)
    assert scene.frame_ids == truth.frame_ids and scene.fps == pytest.approx(truth.fps)
    assert (scene.width, scene.height) == (truth.width, truth.height)
    assert scene.camera_motion == "static"
    # stage 02 is told these are a detector's keypoints (their proportions do not tell a body's size)
    assert CONFIG.fit_size_sigma > 0 and CONFIG.fit_keypoint_noise_m > 0
    assert CONFIG.fit_unseen_limbs_at_rest and CONFIG.fit_up_from_torsos
    assert scene.overrides == {"02_smpl_fit": {"weights": {"size_sigma": CONFIG.fit_size_sigma,
                                                           "keypoint_noise_m": CONFIG.fit_keypoint_noise_m},
                                               "unseen_limbs_at_rest": True, "ground": {"up_from": "torso_axes"}}}
    assert sorted(scene.humans) == ["p0", "p1"]
    for person in scene.humans.values():
        keypoints = read_keypoints2d(person.keypoints2d)
        assert sorted(person.masks) == keypoints.frame_ids.tolist()
        assert keypoints.layout == "coco17" and keypoints.keypoints.shape[1:] == (17, 3)
        confidence = keypoints.keypoints[..., 2]
        assert ((confidence == 0) | (confidence >= CONFIG.keypoint_min_confidence)).all()
        assert (keypoints.keypoints[..., :2][confidence == 0] == 0).all()  # missing joints are not invented
    on_disk = json.loads((scene_dir / REPORT_FILE).read_text())
    assert on_disk["people"].keys() == report["people"].keys() and on_disk["frames"] == len(truth.frame_ids)
    for pid, person in on_disk["people"].items():  # frames whose left/right labels were exchanged (glimpse.ingest.sides)
        assert all(person["first_frame"] <= f <= person["last_frame"]
                   for f in person["sides_exchanged"] + person["legs_exchanged"])
        # frames given a mask from the plate inside a gap (glimpse.ingest.gap_masks) carry no keypoints
        keypoints = read_keypoints2d(scene.humans[pid].keypoints2d)
        rows = [keypoints.frame_ids.tolist().index(f) for f in person["masks_from_foreground"]]
        assert not keypoints.keypoints[rows, :, 2].any()
        assert all(person["first_frame"] < f < person["last_frame"] for f in person["masks_from_foreground"])
    preview = read_mp4(scene_dir / PREVIEW_FILE)
    assert preview.shape[0] == len(truth.frame_ids)


def _bench_ingest():
    """bench/ingest.py, the benchmark's ground-truth side, as a module."""
    import importlib
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
    return importlib.import_module("ingest")


@needs_models
def test_ingest_finds_and_follows_each_true_person(demo_video, ingested) -> None:
    from glimpse.ingest.evaluate import score_people

    bench = _bench_ingest()
    fixture, _ = demo_video
    scene_dir, _ = ingested
    truth = bench.true_people(fixture, ("coco17_skin",))["coco17_skin"]
    scores = score_people(truth, bench.found_people(scene_dir), pck_fraction=0.2)
    assert sorted(scores) == ["p0", "p1"]
    found_as = [s.ids for s in scores.values()]
    for pid, score in scores.items():
        assert score.recall >= 0.8, (pid, score)
        assert score.switches == 0 and len(score.ids) == 1, (pid, score)
        assert score.mask_iou >= 0.7, (pid, score)
        assert score.pck >= 0.7, (pid, score)
    assert found_as[0] != found_as[1]  # two people, two ids


@needs_models
def test_downscale_and_frame_limit_are_stated(demo_video, tmp_path: Path) -> None:
    from dataclasses import replace

    _, video = demo_video
    report = ingest(video, tmp_path / "small", replace(CONFIG, max_side=240, max_frames=8, preview=False))
    assert report["scene_size"] == [240, 180] and report["frames"] == 8 and report["frame_limit"] == 8
    scene = load_scene(tmp_path / "small")
    assert (scene.width, scene.height) == (240, 180) and scene.frame_ids == list(range(8))
    assert not (tmp_path / "small" / PREVIEW_FILE).exists()


@needs_models
def test_an_interrupted_ingest_goes_on_from_its_checkpoint(demo_video, tmp_path: Path, monkeypatch) -> None:
    """Stopped after 9 of 12 frames (checkpoints every 4), run again: it tracks from frame 8 on and writes
    the same scene as an ingest that was never stopped; its work folder is gone."""
    from dataclasses import replace

    from glimpse.ingest.tracker import Tracker

    _, video = demo_video
    config = replace(CONFIG, max_frames=12, checkpoint_frames=4, preview=False, track_min_frames=1)
    whole = tmp_path / "whole"
    ingest(video, whole, config)
    step, calls, stop_at = Tracker.step, [], [10]

    def counted(self, frame_id, image):
        calls.append(frame_id)
        if len(calls) == stop_at[0]:
            raise RuntimeError("killed")  # as a crash or an interrupt: not a verdict on the video
        return step(self, frame_id, image)

    scene = tmp_path / "scene"
    monkeypatch.setattr(Tracker, "step", counted)
    with pytest.raises(RuntimeError, match="killed"):
        ingest(video, scene, config)
    assert (tmp_path / "scene.ingest-work" / "checkpoint.npz").is_file() and not scene.exists()
    calls.clear()
    stop_at[0] = 0  # no more interruptions
    report = ingest(video, scene, config)
    assert report["resumed_after_frames"] == 8 and calls == [8, 9, 10, 11]
    assert not (tmp_path / "scene.ingest-work").exists()
    assert sorted(p.name for p in (scene / "humans").iterdir()) == sorted(p.name for p in (whole / "humans").iterdir())
    for person in (scene / "humans").iterdir():
        ours, theirs = read_keypoints2d(person / "keypoints2d.npz"), read_keypoints2d(whole / "humans" / person.name
                                                                                     / "keypoints2d.npz")
        assert np.array_equal(ours.frame_ids, theirs.frame_ids) and np.array_equal(ours.keypoints, theirs.keypoints)
        assert np.array_equal(ours.relative3d, theirs.relative3d)
        for mask in (person / "masks").iterdir():
            assert mask.read_bytes() == (whole / "humans" / person.name / "masks" / mask.name).read_bytes()
    calls.clear()
    stop_at[0] = 10
    with pytest.raises(RuntimeError, match="killed"):
        ingest(video, tmp_path / "again", config)
    calls.clear()
    stop_at[0] = 0
    ingest(video, tmp_path / "again", replace(config, max_side=240))  # other parameters: the checkpoint is not used
    assert calls == list(range(12))


@needs_models
def test_an_ingested_part_holds_that_part_and_is_ingested_again_when_its_parameters_change(demo_video,
                                                                                           tmp_path: Path) -> None:
    """The scene of frames 10-17 holds exactly the video's frames 10-17 under their own ids; its tracks report
    records the parameters, and a later run with other scene parameters (not with another preview setting), or a
    newer video, says why it ingests again."""
    import os
    import shutil
    from dataclasses import replace

    from glimpse.ingest.stage import why_ingest_again
    from glimpse.io.video import iter_video_frames, resized

    fixture, source = demo_video
    video = Path(shutil.copy(source, tmp_path / "clip.mp4"))
    fps = load_scene(fixture).fps
    config = replace(CONFIG, start_s=10 / fps, end_s=17 / fps, max_side=240, preview=False, track_min_frames=1)
    report = ingest(video, tmp_path / "part", config)
    scene = load_scene(tmp_path / "part")
    assert scene.frame_ids == list(range(10, 18)) and report["segment_s"] == [10 / fps, 17 / fps]
    decoded = dict(iter_video_frames(video, set(range(10, 18)), "reference"))
    for frame_id in scene.frame_ids:
        assert np.array_equal(read_rgb(scene.frame_paths[frame_id]), resized(decoded[frame_id], (240, 180)))
    for person in scene.humans.values():
        assert set(read_keypoints2d(person.keypoints2d).frame_ids) <= set(range(10, 18))
    assert report["parameters"]["start_s"] == 10 / fps and "preview" not in report["parameters"]

    assert why_ingest_again(video, tmp_path / "part", config) is None
    assert why_ingest_again(video, tmp_path / "part", replace(config, preview=True, threads=2)) is None
    assert why_ingest_again(video, tmp_path / "part", replace(config, end_s=None)) == (
        f"ingest parameters changed since it was ingested: ingest.end_s {17 / fps!r} -> None")
    assert why_ingest_again(video, tmp_path / "nothing", config) == "no scene yet"
    later = (tmp_path / "part" / "scene.yaml").stat().st_mtime_ns + 10**9
    os.utime(video, ns=(later, later))
    assert why_ingest_again(video, tmp_path / "part", config) == "the video is newer than the scene"


@needs_models
def test_the_scene_does_not_depend_on_the_models_threads(demo_video, tmp_path: Path) -> None:
    """ingest.threads (auto: compute.threads) is left out of the scene's parameters and of the checkpoint's key,
    because one thread and two write the same keypoints and masks."""
    from dataclasses import replace

    _, video = demo_video
    scenes = []
    for threads in (1, 2):
        config = replace(CONFIG, max_frames=8, max_side=240, preview=False, track_min_frames=1, threads=threads)
        ingest(video, tmp_path / f"threads{threads}", config)
        scenes.append(tmp_path / f"threads{threads}")
    one, two = (sorted((scene / "humans").rglob("*.*")) for scene in scenes)
    assert [p.relative_to(scenes[0]) for p in one] == [p.relative_to(scenes[1]) for p in two] and one
    for a, b in zip(one, two):
        if a.suffix == ".npz":
            x, y = np.load(a), np.load(b)
            assert all(np.array_equal(x[k], y[k]) for k in x.files), a.name
        else:
            assert a.read_bytes() == b.read_bytes(), a.name


@needs_models
def test_user_onnx_models_plug_in(demo_video, tmp_path: Path) -> None:
    """detector: onnx finds people (BlazePose still follows and segments them); pose: onnx gives the keypoints."""
    from dataclasses import replace

    from tests.tiny_onnx import bright_box_detector, brightest_point_pose

    _, video = demo_video
    config = replace(CONFIG, max_frames=6, preview=False, track_min_frames=1, detector="onnx", pose="onnx",
                     detector_onnx_path=bright_box_detector(tmp_path / "det.onnx"),
                     pose_onnx_path=brightest_point_pose(tmp_path / "pose.onnx"), keypoint_min_confidence=0.0)
    ingest(video, tmp_path / "scene", config)
    scene = load_scene(tmp_path / "scene")
    assert scene.humans
    for person in scene.humans.values():
        keypoints = read_keypoints2d(person.keypoints2d).keypoints
        # the stand-in pose model puts all 17 keypoints on one point: the keypoints are its, not BlazePose's
        assert np.ptp(keypoints[..., :2], axis=1).max() < 1e-6


@needs_models
def test_the_median_over_moved_crops_changes_the_keypoints_and_nothing_else(demo_video, tmp_path: Path) -> None:
    """keypoint_crop_shifts: the written keypoints are a median over more crops; the people, their frames and
    masks are the tracking's, the same with and without it, and so are the confidences and metric 3D landmarks
    where the left/right step (which reads the written keypoints) exchanges the same frames, as here."""
    from dataclasses import replace

    from glimpse.io.images import read_mask

    _, video = demo_video
    short = replace(CONFIG, max_frames=8, preview=False, track_min_frames=1,
                    legs_consistent=False)  # the legs step reads the median's runs (who named the legs otherwise)
    assert short.keypoint_crop_shifts
    ingest(video, tmp_path / "median", short)
    ingest(video, tmp_path / "own", replace(short, keypoint_crop_shifts=[]))
    median, own = load_scene(tmp_path / "median"), load_scene(tmp_path / "own")
    exchanged = [{pid: person["sides_exchanged"] for pid, person in json.loads((tmp_path / name / REPORT_FILE)
                                                                             .read_text())["people"].items()}
                 for name in ("median", "own")]
    assert exchanged[0] == exchanged[1]
    assert sorted(median.humans) == sorted(own.humans) and median.humans
    moved = []
    for pid, person in median.humans.items():
        a, b = read_keypoints2d(person.keypoints2d), read_keypoints2d(own.humans[pid].keypoints2d)
        assert a.frame_ids.tolist() == b.frame_ids.tolist() and sorted(person.masks) == sorted(own.humans[pid].masks)
        for frame, path in person.masks.items():
            assert (read_mask(path) == read_mask(own.humans[pid].masks[frame])).all()
        np.testing.assert_array_equal(a.keypoints[..., 2], b.keypoints[..., 2])
        np.testing.assert_array_equal(a.relative3d, b.relative3d)
        found = a.keypoints[..., 2] > 0
        moved.append(np.linalg.norm(a.keypoints[..., :2] - b.keypoints[..., :2], axis=-1)[found])
    moved = np.concatenate(moved)
    assert 0 < np.median(moved) < 5.0  # pixels at 480x360: another estimate of the same points


def test_focal_length_tag_gives_the_intrinsics(tmp_path: Path) -> None:
    from glimpse.ingest.survey import intrinsics_from_focal

    plain = _pattern_video(tmp_path / "plain.mp4", size=(64, 48))
    tagged = tmp_path / "tagged.mp4"
    subprocess.run([_ffmpeg(), "-y", "-loglevel", "error", "-i", str(plain), "-c", "copy", "-movflags",
                    "use_metadata_tags", "-metadata", "com.apple.quicktime.camera.focal_length.35mm_equivalent=26",
                    str(tagged)], check=True)
    assert survey_video(tagged, CONFIG).focal_35mm == 26.0
    assert survey_video(plain, CONFIG).focal_35mm is None
    K = intrinsics_from_focal(26.0, 4000, 3000)  # a phone's main camera: 80 degrees across the diagonal
    assert np.degrees(2 * np.arctan(2500 / K[0, 0])) == pytest.approx(79.5, abs=0.5)
    np.testing.assert_allclose(K[:2, 2], [1999.5, 1499.5])


@needs_models
def test_a_static_video_with_a_focal_length_gets_cameras_json(demo_video, tmp_path: Path) -> None:
    from dataclasses import replace

    from glimpse.ingest.survey import intrinsics_from_focal

    _, video = demo_video
    tagged = tmp_path / "tagged.mp4"
    subprocess.run([_ffmpeg(), "-y", "-loglevel", "error", "-i", str(video), "-c", "copy", "-movflags",
                    "use_metadata_tags", "-metadata", "com.apple.quicktime.camera.focal_length.35mm_equivalent=30",
                    str(tagged)], check=True)
    report = ingest(tagged, tmp_path / "scene", replace(CONFIG, max_frames=6, preview=False))
    scene = load_scene(tmp_path / "scene")
    assert report["focal_35mm_equivalent"] == 30.0 and scene.cameras is not None
    np.testing.assert_allclose(scene.cameras.K, intrinsics_from_focal(30.0, scene.width, scene.height))


def test_the_reference_region_is_mediapipes_alignment_square() -> None:
    from glimpse.ingest.behind import HEAD_TOP_REACH
    from glimpse.ingest.blazepose import REGION_GROW
    from glimpse.ingest.crop import crop_to_image

    bench = _bench_ingest()
    # COCO-17 of an upright person, pixels from the mid hip (y down): the eyes, 168.2 px away, are the farthest
    joints = np.array([[0, -160], [8, -168], [-8, -168], [16, -164], [-16, -164], [40, -100], [-40, -100],
                       [50, -50], [-50, -50], [55, 0], [-55, 0], [20, 0], [-20, 0], [22, 80], [-22, 80],
                       [24, 160], [-24, 160]], float)
    side = 2 * np.hypot(8, 168) * HEAD_TOP_REACH * REGION_GROW
    for turn in (0.0, 0.5):  # radians, the person leaning over
        rotation = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
        region = bench.reference_region(joints @ rotation.T + [300, 200])
        np.testing.assert_allclose(region.centre, [300, 200])
        assert region.side == pytest.approx(side)
        top = crop_to_image(region, np.array([[0.0, -0.5]]), 1)[0]  # the crop's top edge, middle
        np.testing.assert_allclose(top, [300, 200] + rotation @ [0, -side / 2], atol=1e-9)


@needs_models
def test_the_model_shown_each_person_alone_finds_their_joints(demo_video) -> None:
    bench = _bench_ingest()
    fixture, _ = demo_video
    truth = bench.true_people(fixture, ("coco17_skin",))["coco17_skin"]
    reference = bench.model_reference(fixture, truth, CONFIG)
    assert sorted(reference) == ["p0", "p1"]
    assert min(r.pck for r in reference.values()) >= 0.75, reference  # 0.85 and 0.87 at 480x360 (PCK@0.1 in view)
    assert min(r.mask_iou for r in reference.values()) >= 0.80, reference  # 0.90 and 0.90: the segmentation, snapped
