"""The `glimpse` command's surface: version, help with an example for every command, exit statuses."""

import subprocess
import sys

import pytest

import glimpse.cli as cli
from glimpse import __version__
from glimpse.errors import EXIT_BAD_INPUT, EXIT_INTERRUPTED, EXIT_USAGE, GlimpseError
from glimpse.config import REPO_ROOT


def test_version_names_the_release_and_the_commit(capsys):
    with pytest.raises(SystemExit) as stop:
        cli.main(["--version"])
    assert stop.value.code == 0
    printed = capsys.readouterr().out.strip()
    assert printed.startswith(f"glimpse {__version__}+") and len(printed) > len(f"glimpse {__version__}+")


@pytest.mark.parametrize("command", sorted(cli.EXAMPLES))
def test_every_command_has_help_with_an_example_and_the_exit_statuses(command, capsys):
    with pytest.raises(SystemExit) as stop:
        cli.main([command, "--help"])
    assert stop.value.code == 0
    text = capsys.readouterr().out
    assert f"glimpse {command}" in text.split("example:")[1] and "exit statuses:" in text


def test_a_wrong_command_line_exits_2_and_bad_input_3(tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        cli.main(["render"])  # RUN missing
    assert stop.value.code == EXIT_USAGE
    assert cli.main(["validate", str(tmp_path / "missing")]) == EXIT_BAD_INPUT
    assert "no such scene folder" in capsys.readouterr().err
    assert cli.main(["view", str(tmp_path)]) == EXIT_BAD_INPUT  # not a finished run: nothing is served
    assert "no finished stage 06" in capsys.readouterr().err
    assert cli.main(["view", str(tmp_path), "--params", "view.port=-1"]) == EXIT_BAD_INPUT
    assert "pipeline.yaml view: need 0 <= port" in capsys.readouterr().err


def test_an_interrupt_exits_130_with_a_message(monkeypatch, capsys):
    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "_dispatch", interrupted)
    assert cli.main(["validate", "anything"]) == EXIT_INTERRUPTED
    assert "rerun the same command" in capsys.readouterr().err


def test_bad_input_from_a_command_is_one_message_without_a_traceback(monkeypatch, capsys):
    def refuses(args):
        raise GlimpseError("scene.yaml: fps must be > 0")

    monkeypatch.setattr(cli, "_dispatch", refuses)
    assert cli.main(["validate", "anything"]) == EXIT_BAD_INPUT
    assert capsys.readouterr().err == "error: scene.yaml: fps must be > 0\n"


def test_the_installed_entry_point_is_the_module_main():
    """pyproject's console script (what make venv installs as .venv/bin/glimpse) runs glimpse.cli:main."""
    text = (REPO_ROOT / "pyproject.toml").read_text()
    assert 'glimpse = "glimpse.cli:main"' in text
    result = subprocess.run([sys.executable, "-m", "glimpse", "--version"], capture_output=True, text=True,
                            cwd=REPO_ROOT, check=True)
    assert result.stdout.startswith("glimpse ")


def test_run_with_a_video_ingests_it_again_only_when_the_scene_is_not_up_to_date(tmp_path, monkeypatch, capsys):
    """`glimpse run --video` (make all VIDEO=...): a scene made from this video with these ingest parameters is
    run as it is; other scene parameters (the tracks report records those it was made with) ingest it again, and
    the output says which changed."""
    import json
    import os

    import glimpse.ingest.stage as ingest_stage
    import glimpse.pipeline.make as make
    from glimpse.ingest.config import load_ingest_config

    video, scene = tmp_path / "clip.mp4", tmp_path / "scene"
    video.write_bytes(b"a video")
    (scene / "ingest").mkdir(parents=True)
    (scene / "scene.yaml").write_text("name: clip\n")
    later = video.stat().st_mtime_ns + 10**9
    os.utime(scene / "scene.yaml", ns=(later, later))
    recorded = {"parameters": ingest_stage.scene_parameters(load_ingest_config())}
    (scene / "ingest" / "tracks.json").write_text(json.dumps(recorded))
    ingested, stages = [], []
    monkeypatch.setattr(ingest_stage, "ingest", lambda video, scene, config: ingested.append(config.start_s))
    monkeypatch.setattr(make, "run_stages", lambda scene, *rest: stages.append(scene) or 0)
    command = ["run", "--video", str(video), "--scene", str(scene), "--out", str(tmp_path / "runs")]
    assert cli.main(command + ["--params", "ingest.preview=false"]) == 0  # not a scene parameter
    assert ingested == [] and stages == [scene]
    assert cli.main(command + ["--params", "ingest.start_s=2.0"]) == 0
    assert ingested == [2.0] and stages == [scene, scene]
    assert (f"{scene}: ingest parameters changed since it was ingested: ingest.start_s 0.0 -> 2.0; ingesting "
            f"{video} again") in capsys.readouterr().out
