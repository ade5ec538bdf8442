"""The Makefile DAG, end to end through make: reruns exactly what changed.

The real Makefile, mk/pipeline.mk, `glimpse run` and the stage runner are
used; only the stage bodies are replaced (STAGES_DIR) by scripts that record
that they ran, so the test does not depend on which stages have landed.
"""

import json
import os
import signal
import subprocess
import time

import numpy as np
import pytest
import yaml
from PIL import Image

from glimpse.pipeline.prepare import prepare_run
from glimpse.pipeline.stages import STAGES, STAGE_NAMES
from tests.make_helpers import REPO, make, make_setup, ran


@pytest.fixture()
def setup(tmp_path):
    return make_setup(tmp_path, tmp_path / "scene", tmp_path / "out")


def test_the_stage_folders_are_the_registry_and_make_follows_its_dag(setup):
    assert sorted(p.parent.name for p in (REPO / "stages").glob("*/run.py")) == sorted(STAGE_NAMES)
    scene, out, log, env, args = setup
    run, _ = prepare_run(scene, out)
    dag = {}
    for line in run.dag_file.read_text().splitlines():
        if line.startswith("DEPS_"):
            name, _, upstream = line.removeprefix("DEPS_").partition(":=")
            dag[name.strip()] = tuple(upstream.split())
    assert dag == {s.name: s.upstream for s in STAGES}
    dry = subprocess.run(["make", "-n", "-C", str(run.root), "-f", str(REPO / "mk" / "pipeline.mk"), "all"],
                         capture_output=True, text=True)  # what make would run
    assert dry.returncode == 0, dry.stderr
    commands = [line for line in dry.stdout.splitlines() if "/run.py" in line]
    assert [c.split("/run.py")[0].rsplit("/", 1)[1] for c in commands] == list(STAGE_NAMES)


def test_reruns_exactly_the_changed_stage_and_its_descendants(setup):
    scene, out, log, env, args = setup
    first = make(args, env)
    assert first.returncode == 0, first.stderr
    order = ran(log, 0)
    assert sorted(order) == sorted(STAGE_NAMES)
    for spec in STAGES:  # topological order
        assert all(order.index(up) < order.index(spec.name) for up in spec.upstream)
    manifest = json.loads((out / "tiny" / "01_sfm" / "manifest.json").read_text())
    assert manifest["format"] == "glimpse-manifest/1" and manifest["stage"] == "01_sfm"
    assert set(manifest["params"]) == {"01_sfm", "compute"}
    assert "frames/000000.png" in manifest["inputs"]["scene_files"]
    assert not (out / "tiny" / ".tmp").exists() or not any((out / "tiny" / ".tmp").iterdir())

    n = len(ran(log, 0))
    again = make(args, env)
    assert again.returncode == 0 and ran(log, n) == [], again.stdout
    assert "Nothing to be done" in again.stdout

    changed = make(args, env, "PARAMS=04_bg_pretrain.knob=2")
    assert changed.returncode == 0, changed.stderr
    assert sorted(ran(log, n)) == ["04_bg_pretrain", "06_joint_opt", "07_eval"]
    assert json.loads((out / "tiny" / "04_bg_pretrain" / "params.json").read_text())["04_bg_pretrain"]["knob"] == 2

    n = len(ran(log, 0))  # a shared key reaches exactly the stages that declare it
    make(args, env, "PARAMS=04_bg_pretrain.knob=2 body.skinning.grid_resolution=32")
    assert sorted(ran(log, n)) == ["06_joint_opt", "07_eval"]
    n = len(ran(log, 0))
    make(args, env, "PARAMS=04_bg_pretrain.knob=2 body.skinning.grid_resolution=32 render.sh_degree=1")
    assert sorted(ran(log, n)) == ["04_bg_pretrain", "06_joint_opt", "07_eval"]
    params = json.loads((out / "tiny" / "07_eval" / "params.json").read_text())
    assert params["body"] == {"model_path": "glimpse/body/assets/free_body.npz",  # what stage 07 reads of body
                              "person_model_paths": []}
    n = len(ran(log, 0))
    make(args, env, "PARAMS=04_bg_pretrain.knob=2 body.skinning.grid_resolution=32 render.sh_degree=1 "
                    "compute.seed=5")
    assert sorted(ran(log, n)) == sorted(STAGE_NAMES)

    n = len(ran(log, 0))  # scene.yaml overrides are parameters too; other scene.yaml edits are inputs
    config = yaml.safe_load((scene / "scene.yaml").read_text())
    config["overrides"] = {"05_textual_inversion": {"knob": 7}}
    (scene / "scene.yaml").write_text(yaml.safe_dump(config))
    make(args, env, "PARAMS=04_bg_pretrain.knob=2 body.skinning.grid_resolution=32 render.sh_degree=1 "
                    "compute.seed=5")
    assert sorted(ran(log, n)) == ["05_textual_inversion", "06_joint_opt", "07_eval"]
    kept = "PARAMS=04_bg_pretrain.knob=2 body.skinning.grid_resolution=32 render.sh_degree=1 compute.seed=5"

    n = len(ran(log, 0))  # clean-stage removes one output; make all rebuilds it and its descendants
    cleaned = make(args, env, "STAGE=05_textual_inversion", target="clean-stage")
    assert cleaned.returncode == 0 and not (out / "tiny" / "05_textual_inversion").exists()
    assert (out / "tiny" / "04_bg_pretrain" / "manifest.json").exists()
    make(args, env, kept)
    assert sorted(ran(log, n)) == ["05_textual_inversion", "06_joint_opt", "07_eval"]

    n = len(ran(log, 0))  # one stage on request; its descendants wait for `make all`
    single = make(args, env, kept, target="03_masks")
    assert single.returncode == 0, single.stderr
    assert ran(log, n) == ["03_masks"]

    n = len(ran(log, 0))  # a changed scene file reruns the stages that read it
    Image.fromarray(np.zeros((12, 16, 3), np.uint8)).save(scene / "frames" / "000001.png")
    make(args, env, kept)
    assert ran(log, n)[0] == "01_sfm" and sorted(ran(log, n)) == sorted(STAGE_NAMES)


def test_a_stage_that_reads_a_shared_key_it_does_not_declare_is_not_published(setup, monkeypatch):
    from glimpse.pipeline import runner

    scene, out, log, env, args = setup
    monkeypatch.setenv("GLIMPSE_PIPELINE_YAML", str(out.parent / "pipeline.yaml"))

    def body(ctx) -> None:  # stage 01 declares compute.seed and compute.threads, nothing of body
        ctx.section("compute").seed
        ctx.section("body").skinning.knn

    with pytest.raises(RuntimeError, match=r"stage 01_sfm read body\.skinning\.knn, which"):
        runner.run_stage("01_sfm", scene, out, "", body)
    assert not (out / "tiny" / "01_sfm").exists()
    runner.run_stage("01_sfm", scene, out, "", lambda ctx: ctx.section("compute").seed)
    manifest = json.loads((out / "tiny" / "01_sfm" / "manifest.json").read_text())
    assert manifest["params"]["compute"] == {"seed": 0} and set(manifest["params"]) == {"01_sfm", "compute"}


def test_a_killed_stage_leaves_the_previous_output(setup):
    scene, out, log, env, args = setup
    assert make(args, env).returncode == 0
    stage_dir = out / "tiny" / "02_smpl_fit"
    before = {p.name: p.read_bytes() for p in stage_dir.iterdir()}
    proc = subprocess.Popen([*args, "all", "PARAMS=02_smpl_fit.knob=9"], env=dict(env, SLOW_STAGE="02_smpl_fit"),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.time() + 60
    while "02_smpl_fit" not in ran(log, len(STAGE_NAMES)) and time.time() < deadline:
        time.sleep(0.1)
    time.sleep(0.3)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert {p.name: p.read_bytes() for p in stage_dir.iterdir()} == before
    assert json.loads((stage_dir / "params.json").read_text())["02_smpl_fit"]["knob"] == 1
    result = make(args, env, "PARAMS=02_smpl_fit.knob=9")  # the next run redoes it and cleans up
    assert result.returncode == 0, result.stderr
    assert json.loads((stage_dir / "params.json").read_text())["02_smpl_fit"]["knob"] == 9
    assert not any((out / "tiny" / ".tmp").iterdir())


def test_bad_parameters_stop_before_any_stage(setup):
    scene, out, log, env, args = setup
    result = make(args, env, "PARAMS=01_sfm.mdoe=sfm")
    assert result.returncode != 0
    assert "unknown parameter '01_sfm.mdoe'" in result.stderr and "known keys of 01_sfm" in result.stderr
    assert ran(log, 0) == [] and not (out / "tiny").exists()
