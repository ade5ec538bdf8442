"""Every stage leaves a log.txt beside its manifest (a failed one a <stage>.failed.log.txt in the run folder), and
progress shows as timed lines when the output is not a terminal."""

import json
import logging
import warnings

import pytest

import glimpse.io.progress as progress_module
from glimpse.errors import GlimpseError
from glimpse.io.progress import Progress, progress
from glimpse.pipeline.runner import LOG_FILE, run_stage
from tests.make_helpers import write_tiny_scene
from tests.stage_helpers import run

STAGE_LOG = logging.getLogger("glimpse.test_stage")


def test_a_finished_stage_has_its_log_beside_its_manifest(tmp_path):
    write_tiny_scene(tmp_path / "scene")
    out = run("01_sfm", tmp_path / "scene", tmp_path / "runs")
    text = (out / LOG_FILE).read_text()
    manifest = json.loads((out / "manifest.json").read_text())
    assert LOG_FILE in manifest["formats"]
    assert "01_sfm on" in text and ("summary:" in text) == bool(manifest["summary"])
    assert f"finished in {manifest['timings_s']['total']:.1f} s" in text


def test_a_failed_stage_keeps_its_log_with_warnings_and_the_reason_and_a_rerun_clears_it(tmp_path):
    write_tiny_scene(tmp_path / "scene")

    def fails(ctx):
        STAGE_LOG.info("read 3 frames")
        warnings.warn("a frame is darker than the rest", UserWarning)
        raise GlimpseError("frame 000002.png: unreadable")

    with pytest.raises(GlimpseError):
        run_stage("01_sfm", tmp_path / "scene", tmp_path / "runs", "", fails)
    failed = tmp_path / "runs" / "tiny" / f"01_sfm.failed.{LOG_FILE}"
    text = failed.read_text()
    assert "read 3 frames" in text and "a frame is darker than the rest" in text
    assert "stopped: frame 000002.png: unreadable" in text and "Traceback" not in text
    assert not (tmp_path / "runs" / "tiny" / "01_sfm").exists()
    run("01_sfm", tmp_path / "scene", tmp_path / "runs")
    assert not failed.exists()


def test_progress_off_a_terminal_is_timed_log_lines(monkeypatch, caplog):
    monkeypatch.setattr(progress_module, "on_terminal", lambda: False)
    monkeypatch.setattr(progress_module, "LINE_EVERY_S", 0.0)
    with caplog.at_level(logging.INFO, logger="glimpse.progress"):
        assert list(progress(range(3), desc="03_masks", unit="frame")) == [0, 1, 2]
        bar = Progress(10, "06 joint", "iteration", initial=4)
        bar.update(1, postfix={"loss": "0.0107"})
        bar.close()
    lines = [r.getMessage() for r in caplog.records]
    heads = [line.split(" (")[0] for line in lines]
    assert heads[:4] == ["03_masks: 1/3 frames", "03_masks: 2/3 frames", "03_masks: 3/3 frames",
                         "03_masks: 3/3 frames"]  # one line an item (no wait between lines here), then the closing one
    assert heads[4] == "06 joint: 5/10 iterations" and lines[4].endswith("; loss 0.0107")


def test_progress_off_a_terminal_is_quiet_between_lines(monkeypatch, caplog):
    monkeypatch.setattr(progress_module, "on_terminal", lambda: False)
    with caplog.at_level(logging.INFO, logger="glimpse.progress"):
        assert sum(progress(range(1000), desc="frames", unit="frame")) == 499500
    assert [r.getMessage().split(" (")[0] for r in caplog.records] == ["frames: 1000/1000 frames"]


def test_a_bug_leaves_its_traceback_in_the_failed_log(tmp_path):
    write_tiny_scene(tmp_path / "scene")

    def breaks(ctx):
        raise RuntimeError("index out of range in the fit")

    with pytest.raises(RuntimeError):
        run_stage("01_sfm", tmp_path / "scene", tmp_path / "runs", "", breaks)
    text = (tmp_path / "runs" / "tiny" / f"01_sfm.failed.{LOG_FILE}").read_text()
    assert "stopped: index out of range in the fit" in text and "Traceback" in text and "in breaks" in text
