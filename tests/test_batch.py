"""Batches: two tiny fixture scenes end to end with the local executor and on a local Ray cluster, one of them
made to fail once in stage 04 (as a pre-empted job would) and resumed; the Slurm path through submitit's local
executor and the submission script it writes for a real cluster; the summary."""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path

import pytest
import yaml

from glimpse.batch.config import RayConfig, SlurmConfig
from glimpse.batch.executors import SceneTask, run_ray, run_slurm, slurm_parameters
from glimpse.batch.jobs import SceneJob
from glimpse.batch.summary import write_summary
from glimpse.cli import main as cli
from glimpse.config import REPO_ROOT
from glimpse.errors import EXIT_BAD_INPUT
from glimpse.fixtures.scenes import make_scene

FAST = ("04_bg_pretrain.schedule_scale=0.005 06_joint_opt.schedule_scale=0.005 07_eval.renders.enabled=false "
        "07_eval.speed.enabled=false")
FAILING_STAGE = "04_bg_pretrain"
STAGES = ["01_sfm", "02_smpl_fit", "03_masks", "04_bg_pretrain", "05_textual_inversion", "06_joint_opt", "07_eval"]
WRAPPER = '''"""Test double of stage 04: fails once for the scene named in $GLIMPSE_TEST_FAIL_SCENE, then runs the real one."""
import os, runpy, sys
from pathlib import Path
marker = Path(os.environ["GLIMPSE_TEST_FAIL_MARKER"])
scene = sys.argv[sys.argv.index("--scene") + 1]
if Path(scene).name == os.environ["GLIMPSE_TEST_FAIL_SCENE"] and not marker.exists():
    marker.write_text("failed once")
    sys.exit("stage 04 stopped (a simulated pre-emption)")
runpy.run_path(os.environ["GLIMPSE_TEST_REAL_STAGE"], run_name="__main__")
'''


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """Two tiny scenes with distinct names, and stage scripts whose stage 04 fails once for the second."""
    root = tmp_path_factory.mktemp("batch")
    folders = []
    for label, seed in (("alpha", 0), ("beta", 1)):
        scene = make_scene("demo", root / label, "tiny", seed=seed)
        meta = yaml.safe_load((scene / "scene.yaml").read_text())
        meta["name"] = f"tiny_{label}"
        (scene / "scene.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
        folders.append(scene)
    stages = root / "stages"
    stages.mkdir()
    for stage in STAGES:
        if stage == FAILING_STAGE:
            (stages / stage).mkdir()
            (stages / stage / "run.py").write_text(WRAPPER)
        else:
            (stages / stage).symlink_to(REPO_ROOT / "stages" / stage)
    return folders, stages


def failing_env(stages: Path, marker: Path) -> dict[str, str]:
    return {"GLIMPSE_STAGES_DIR": str(stages), "GLIMPSE_TEST_FAIL_MARKER": str(marker),
            "GLIMPSE_TEST_FAIL_SCENE": "beta", "GLIMPSE_TEST_REAL_STAGE": str(REPO_ROOT / "stages" / FAILING_STAGE /
                                                                            "run.py")}


def check_resumed(results) -> None:
    """alpha ran through once; beta stopped in stage 04, then resumed there (01-03 not run again)."""
    alpha, beta = results
    assert alpha.status == beta.status == "done"
    assert [a.stages_run for a in alpha.attempts] == [STAGES]
    assert [a.exit_code for a in beta.attempts] == [1, 0]
    assert beta.attempts[0].stages_run == STAGES[:3] and beta.attempts[1].stages_run == STAGES[3:]
    assert "simulated pre-emption" in Path(beta.attempts[0].log).read_text()
    for result in results:
        assert result.headline["humans_psnr_db"] > 10 and Path(result.run_dir, "07_eval", "metrics.json").is_file()


@pytest.fixture(scope="module")
def local_batch(scenes, tmp_path_factory):
    """The local executor, two scenes at once, on both scenes (one given twice); beta fails once."""
    folders, stages = scenes
    root = tmp_path_factory.mktemp("local")
    saved = dict(os.environ)
    os.environ.update(failing_env(stages, root / "failed_once"))
    try:
        code = cli(["batch", *map(str, folders), str(folders[0]), "--executor", "local", "--out", str(root / "out"),
                    "--jobs", "2", "--retries", "1", "--params", FAST + " batch.lock_wait_s=5"])
    finally:
        os.environ.clear()
        os.environ.update(saved)
    return code, root / "out"


def test_local_batch_runs_every_scene_resumes_the_failed_one_and_summarises(local_batch):
    code, out = local_batch
    assert code == 0
    doc = json.loads((out / "batch.json").read_text())
    assert doc["format"] == "glimpse-batch/1" and doc["counts"] == {"done": 2, "failed": 0, "bad input": 0, "interrupted": 0}
    assert [s["label"] for s in doc["scenes"]] == ["alpha", "beta"]  # the repeated source ran once
    from glimpse.batch.jobs import Attempt, SceneResult

    check_resumed([SceneResult(**{**s, "attempts": [Attempt(**a) for a in s["attempts"]]}) for s in doc["scenes"]])
    values = [s["headline"]["humans_psnr_db"] for s in doc["scenes"]]
    assert doc["aggregate"]["humans_psnr_db"]["mean"] == pytest.approx(sum(values) / 2)
    table = (out / "batch.md").read_text()
    assert "| alpha | done | 1 | 01,02,03,04,05,06,07 |" in table
    assert "| beta | done | 2 | 01,02,03; 04,05,06,07 |" in table and "**mean ± std**" in table


def test_ray_runs_one_task_per_scene_on_a_local_cluster(scenes, tmp_path):
    ray = pytest.importorskip("ray")
    folders, stages = scenes
    out = tmp_path / "out"
    env = failing_env(stages, tmp_path / "failed_once")
    jobs = [SceneJob(folder, out, FAST, threads=1, attempts=2, python=os.sys.executable, env=env)
            for folder in folders]
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        results = run_ray(jobs, RayConfig(address="", cpus_per_job=1, gpus_per_job=0, memory_gb=0.5), retries=1,
                          report=lambda result: None)
    finally:
        ray.shutdown()
    check_resumed(results)


def test_slurm_path_runs_through_submitit_and_writes_the_submission_script(scenes, local_batch, tmp_path,
                                                                          monkeypatch):
    pytest.importorskip("submitit")
    folders, _ = scenes
    out = local_batch[1]  # finished by the local batch: resubmitted, nothing runs again
    config = SlurmConfig(partition="gpu", time_min=90, cpus_per_job=2, gpus_per_job=1, mem_gb=48,
                         array_parallelism=32, account="lab", qos="", setup=["module load cuda/12.4"])
    job = SceneJob(folders[0], out, FAST, threads=2, attempts=1, python=os.sys.executable)
    (result,) = run_slurm([job], config, tmp_path / "local", report=lambda r: None, cluster="local")
    assert result.status == "done" and result.attempts[0].stages_run == [] and result.headline

    # a real cluster: what sbatch receives (a stand-in sbatch records it; srun only has to exist)
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for name, body in (("sbatch", f'cp "$1" "{tmp_path}/script.sh"\necho "Submitted batch job 4242"\n'),
                       ("srun", "exit 0\n")):
        (bin_dir / name).write_text("#!/bin/sh\n" + body)
        (bin_dir / name).chmod(stat.S_IRWXU)
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    import submitit

    executor = submitit.AutoExecutor(folder=tmp_path / "slurm", cluster="slurm")
    executor.update_parameters(**slurm_parameters(config))
    submitted = executor.map_array(SceneTask(), [job, job])
    assert [j.job_id for j in submitted] == ["4242_0", "4242_1"]
    script = (tmp_path / "script.sh").read_text()
    for line in ("#SBATCH --partition=gpu", "#SBATCH --time=90", "#SBATCH --gpus-per-node=1",
                 "#SBATCH --cpus-per-task=2", "#SBATCH --mem=48GB", "#SBATCH --array=0-1%2", "#SBATCH --account=lab",
                 "#SBATCH --signal=USR2@90", "module load cuda/12.4"):
        assert line in script, line
    assert "--qos" not in script


def test_bad_sources_are_named_and_summaries_count_failures(scenes, tmp_path, capsys):
    folders, _ = scenes
    assert cli(["batch", str(folders[0]), str(tmp_path / "nothing"), "--out", str(tmp_path / "o")]) == EXIT_BAD_INPUT
    assert "nor a video: " + str(tmp_path / "nothing") in capsys.readouterr().err
    twin = tmp_path / "twin"
    twin.mkdir()
    (twin / "scene.yaml").write_text((folders[0] / "scene.yaml").read_text())
    assert cli(["batch", str(folders[0]), str(twin), "--out", str(tmp_path / "o")]) == EXIT_BAD_INPUT
    assert "share the scene name tiny_alpha" in capsys.readouterr().err
    profile = tmp_path / "profile.yaml"
    profile.write_text("partitions: gpu\n")
    assert cli(["batch", str(folders[0]), "--executor", "slurm", "--slurm-profile", str(profile)]) == EXIT_BAD_INPUT
    assert "partitions" in capsys.readouterr().err
    video = SceneJob(tmp_path / "take 1.mp4", tmp_path / "o", "compute.seed=1", threads=4, lock_wait_s=5)
    command = video.command()
    assert video.is_video and video.scene_dir == tmp_path / "o" / "scenes" / "take 1"  # ingested there first
    assert command[command.index("--video") + 1] == str(tmp_path / "take 1.mp4")
    assert command[command.index("--params") + 1] == "compute.seed=1 compute.threads=4"
    assert command[command.index("--wait") + 1] == "5"
    from glimpse.batch.jobs import Attempt, SceneResult

    failed = SceneResult("gamma", "/x", "failed", None, [Attempt(1, 1, 2.0, ["01_sfm"], "/x.log")], 2.0, {}, "boom")
    _, md = write_summary([failed], "local", tmp_path)
    text = md.read_text()
    assert "1 failed" in text and "## gamma: failed" in text and "boom" in text
