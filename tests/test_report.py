"""The run report: its pieces (parameter differences, the Markdown it renders, stills, log warnings) and a
report of a run that has not finished (the whole page in a browser: test_joint.py, on a finished run)."""

from __future__ import annotations

import numpy as np
import pytest

from glimpse.cli import main as cli
from glimpse.errors import EXIT_BAD_INPUT
from glimpse.fixtures.scenes import make_scene
from glimpse.report.figures import mask_overlay, person_colour, scaled_to_height, spread_indices
from glimpse.report.html import markdown, table
from glimpse.report.run_record import changed_params, read_run, warnings_in_log
from glimpse.report.sections import seen_beside_never_seen
from tests.stage_helpers import run


def test_seen_and_never_seen_rows_stand_side_by_side_by_label():
    def row(label, psnr):
        return {"label": label, "psnr": psnr, "ssim": 0.5, "lpips": 7.0}

    tables = {"seen": {"rows": [row("humans only", 30.0), row("baseline: bodies in mean colour", 24.0)]},
              "never_seen": {"rows": [row("humans only", 15.0), row("baseline: empty render (black)", 9.0)]}}
    html = seen_beside_never_seen(tables)
    body = html.split("<tbody>")[1]
    rendered = body.split("</tr>")
    assert "humans only" in rendered[0] and "30.000" in rendered[0] and "15.000" in rendered[0]
    assert "bodies in mean colour" in rendered[1] and "24.000" in rendered[1] and rendered[1].count("<td>-</td>") == 3
    assert "empty render" in rendered[2] and "9.000" in rendered[2] and rendered[2].count("<td>-</td>") == 3
    assert seen_beside_never_seen({"humans": {"rows": [row("humans only", 1.0)]}}) == ""


def test_changed_parameters_are_the_leaves_that_differ_from_the_defaults():
    defaults = {"06_joint_opt": {"schedule_scale": "auto", "loss": {"lpips": 0.1, "ssim": 0.2}},
                "compute": {"seed": 0}}
    recorded = {"06_joint_opt": {"schedule_scale": 0.02, "loss": {"lpips": 0.1, "ssim": 0.3}, "new": 1},
                "compute": {"seed": 0}}
    assert changed_params(recorded, defaults) == [("06_joint_opt.loss.ssim", 0.3, 0.2),
                                                  ("06_joint_opt.new", 1, None),
                                                  ("06_joint_opt.schedule_scale", 0.02, "auto")]
    assert changed_params(defaults, defaults) == []


def test_markdown_of_glimpse_tables_becomes_html_tables_with_protocols_folded():
    text = ("# Humans only\n\n| | PSNR ↑ (dB) | frames |\n| --- | ---: | ---: |\n| a<b | 22.18 | 4 |\n\n"
            "Protocol:\n- mask: `union`\n- background: black\n\nA closing line.\n")
    html = markdown(text)
    assert "<h3>Humans only</h3>" in html
    assert "<tr><th></th><th>PSNR ↑ (dB)</th><th>frames</th></tr>" in html
    assert "<td>a&lt;b</td><td class=num>22.18</td><td class=num>4</td>" in html  # escaped; numbers right
    assert "<details><summary>Protocol</summary><ul><li>mask: <code>union</code></li>" in html
    assert html.endswith("<p>A closing line.</p>") and "---" not in html
    assert "<thead>" not in table(None, [["key", 1.23456]]) and ">1.235<" in table(["k", "v"], [["key", 1.23456]])


def test_stills_are_spread_over_the_video_and_masks_tinted_in_each_persons_colour():
    assert spread_indices(10, 4) == [0, 3, 6, 9] and spread_indices(3, 4) == [0, 1, 2] and spread_indices(0, 4) == []
    frame = np.full((4, 6, 3), 100, np.uint8)
    first, second = np.zeros((4, 6), bool), np.zeros((4, 6), bool)
    first[0, 0], second[3, 5] = True, True
    out = mask_overlay(frame, [first, None, second], 0.5)
    assert tuple(out[0, 0]) == tuple(round(0.5 * 100 + 0.5 * c) for c in person_colour(0))
    assert tuple(out[3, 5]) == tuple(round(0.5 * 100 + 0.5 * c) for c in person_colour(2))
    assert (out[1:3] == 100).all()
    big = scaled_to_height(np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3), 4)
    assert big.shape == (4, 6, 3) and (big[::2, ::2] == np.arange(18).reshape(2, 3, 3)).all()  # nearest


def test_the_logs_warnings_are_quoted_without_their_times(tmp_path):
    log = tmp_path / "log.txt"
    log.write_text("2026-01-01 10:00:00 INFO glimpse: started\n"
                   "2026-01-01 10:00:01 WARNING glimpse.fit: p1 has 3 frames\n"
                   "2026-01-01 10:00:02 ERROR glimpse: stopped: x\n"
                   "2026-01-01 10:00:03 WARNING glimpse: third\n")
    assert warnings_in_log(log, 2) == ["WARNING glimpse.fit: p1 has 3 frames", "ERROR glimpse: stopped: x"]
    assert warnings_in_log(tmp_path / "missing.txt", 5) == []


@pytest.fixture(scope="module")
def half_run(tmp_path_factory):
    """The tiny demo through stage 03 only."""
    root = tmp_path_factory.mktemp("report")
    scene = make_scene("demo", root / "scene", "tiny", seed=1)
    for stage in ("01_sfm", "02_smpl_fit", "03_masks"):
        run(stage, scene, root / "out", "03_masks.refine=none")
    return root / "out" / "demo_tiny"


def test_a_run_that_stopped_early_has_a_report_of_what_finished(half_run, capsys):
    stale = half_run / "report_files" / "stale.png"
    stale.parent.mkdir(exist_ok=True)
    stale.write_bytes(b"old")
    assert cli(["report", str(half_run)]) == 0
    assert f"wrote {half_run / 'report.html'}" in capsys.readouterr().out
    text = (half_run / "report.html").read_text()
    assert "No metrics yet: stage 07_eval has not run." in text and "Stage 04_bg_pretrain has not run" in text
    masks = sorted(p.name for p in (half_run / "report_files").glob("masks_*.png"))
    assert len(masks) == 4 and all(f'src="report_files/{name}"' in text for name in masks)
    assert not stale.exists()  # the page folder is written anew
    assert "03_masks.refine" in text and "&#x27;none&#x27;" in text  # the override, against its default
    assert set(read_run(half_run).manifests) == {"01_sfm", "02_smpl_fit", "03_masks"}


def test_report_refuses_a_folder_that_is_not_a_run(tmp_path, capsys):
    assert cli(["report", str(tmp_path / "nowhere")]) == EXIT_BAD_INPUT
    assert "not a run folder" in capsys.readouterr().err and not (tmp_path / "nowhere").exists()
