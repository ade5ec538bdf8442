"""What Glimpse promises about a run folder (docs/reliability.md): it never runs code found there, one run at
a time holds it, user paths are never read by a shell, and stamps follow content, not paths or clocks."""

import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from glimpse.errors import EXIT_BAD_INPUT
from glimpse.io.checkpoint import CHECKPOINT_FORMAT, load_checkpoint, save_checkpoint
from glimpse.locks import LockBusy, exclusive_lock, read_holder
from glimpse.pipeline.runner import remove_orphans, temp_name
from glimpse.pipeline.stages import STAGE_NAMES
from glimpse.scene import validate_scene
from tests.make_helpers import REPO, make, make_setup, ran


class _Payload:
    """Unpickling this calls Path.touch on a marker: harmless proof that code would have run."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return Path.touch, (self.marker,)


def test_a_hostile_checkpoint_is_refused_without_running_anything(tmp_path, caplog):
    marker, path = tmp_path / "code-ran", tmp_path / "checkpoint.pt"
    torch.save({"format": CHECKPOINT_FORMAT, "fingerprint": "k", "state": {"step": 1, "x": _Payload(marker)}}, path)
    assert load_checkpoint(path, "k") is None
    assert not marker.exists() and "ignoring unreadable checkpoint" in caplog.text
    save_checkpoint(path, "k", {"step": 3, "losses": [(1, 0.5)], "moments": {"m": torch.ones(2)}})
    assert load_checkpoint(path, "k")["step"] == 3  # a real one still resumes


UNSAFE_LOADS = [
    (re.compile(r"weights_only\s*=\s*False"), "torch.load must keep weights_only=True"),
    (re.compile(r"allow_pickle\s*=\s*True"), "numpy archives are read without pickle"),
    (re.compile(r"\bpickle\.loads?\("), "pickles go through a restricted Unpickler subclass"),
    (re.compile(r"\byaml\.(?:unsafe_load|full_load|load_all|unsafe_load_all|full_load_all)\(|"
                r"\byaml\.load\((?!\w+, Loader=(?:yaml\.CSafeLoader if \w+ else )?yaml\.SafeLoader\))"),
     "YAML is read with a safe loader (yaml.safe_load, or yaml.load(x, Loader=yaml.SafeLoader), where libyaml's "
     "CSafeLoader may stand first: yaml.CSafeLoader if ... else yaml.SafeLoader)"),
    (re.compile(r"shell\s*=\s*True"), "subprocesses get argument lists, never a shell"),
    (re.compile(r"\bos\.system\(|\bos\.popen\("), "subprocesses get argument lists, never a shell"),
    (re.compile(r"(?<![\w.])(?:eval|exec)\("), "no code is built from text"),
]


def test_no_code_reads_files_in_a_way_that_could_run_code():
    offenders = []
    for folder in ("glimpse", "stages", "tools", "bench"):
        for path in sorted((REPO / folder).rglob("*.py")):
            for number, line in enumerate(path.read_text().splitlines(), 1):
                offenders += [f"{path.relative_to(REPO)}:{number}: {why}: {line.strip()}"
                              for pattern, why in UNSAFE_LOADS if pattern.search(line.split("#")[0])]
    assert not offenders, "\n".join(offenders)
    loads = [line for path in (REPO / "glimpse").rglob("*.py") for line in path.read_text().splitlines()
             if "torch.load(" in line]
    assert loads and all("weights_only=True" in line for line in loads)


HOLDER = """
import sys, time
sys.path.insert(0, {repo!r})
from glimpse.locks import exclusive_lock
with exclusive_lock({lock!r}, "a test holder"):
    print("held", flush=True)
    time.sleep(60)
"""


def _start_holder(lock: Path) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", HOLDER.format(repo=str(REPO), lock=str(lock))],
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_a_lock_names_its_holder_waits_for_it_and_dies_with_it(tmp_path):
    lock = tmp_path / "run" / ".lock"
    holder = _start_holder(lock)
    try:
        with pytest.raises(LockBusy, match=rf"in use by pid {holder.pid} on {re.escape(socket.gethostname())} "
                                           r"\(a test holder, since"):
            with exclusive_lock(lock, "a second run"):
                pass
        started = time.monotonic()
        with pytest.raises(LockBusy, match=r"waited 0\.5 s"):
            with exclusive_lock(lock, "a patient run", wait_s=0.5):
                pass
        assert time.monotonic() - started >= 0.5
    finally:
        holder.kill()  # kill -9: the kernel lets go of the lock, no stale file blocks the next run
        holder.wait()
    with exclusive_lock(lock, "the next run"):
        assert read_holder(lock).pid == os.getpid()


def test_a_lock_handed_down_to_a_child_process_is_held_by_it(tmp_path):
    lock = tmp_path / ".lock"
    child = (f"import sys; sys.path.insert(0, {str(REPO)!r})\n"
             f"from glimpse.locks import exclusive_lock\n"
             f"with exclusive_lock({str(lock)!r}, 'child', env_var='TEST_LOCK'):\n    print('inside')")
    with exclusive_lock(lock, "parent", env_var="TEST_LOCK") as fd:
        inherited = subprocess.run([sys.executable, "-c", child], pass_fds=(fd,), capture_output=True, text=True)
        assert inherited.stdout.strip() == "inside", inherited.stderr
        stranger = subprocess.run([sys.executable, "-c", child], env={**os.environ, "TEST_LOCK": ""},
                                  capture_output=True, text=True)
        assert stranger.returncode != 0 and "in use by pid" in stranger.stderr
    assert "TEST_LOCK" not in os.environ


def test_only_temporary_folders_of_dead_writers_are_removed(tmp_path):
    sleeper, zombie = subprocess.Popen(["sleep", "30"]), subprocess.Popen(["true"])
    host, dead_pid = socket.gethostname(), subprocess.Popen(["true"])
    dead_pid.wait()
    time.sleep(0.3)  # `zombie` has exited and is not reaped yet
    try:
        live, dead = tmp_path / f"04_bg_pretrain-{host}-{sleeper.pid}", tmp_path / f"04_bg_pretrain-{host}-{dead_pid.pid}"
        unreaped = tmp_path / f"04_bg_pretrain-{host}-{zombie.pid}"
        foreign, old_style = tmp_path / "04_bg_pretrain-another-host-77", tmp_path / "04_bg_pretrain-12"
        ours, other_stage = tmp_path / temp_name("04_bg_pretrain"), tmp_path / f"06_joint_opt-{host}-{dead_pid.pid}"
        for folder in (live, dead, unreaped, foreign, old_style, ours, other_stage):
            folder.mkdir()
        remove_orphans(tmp_path, "04_bg_pretrain-")
        assert live.exists() and other_stage.exists()
        assert not any(folder.exists() for folder in (dead, unreaped, foreign, old_style, ours))
    finally:
        sleeper.kill()
        for process in (sleeper, zombie):
            process.wait()


@pytest.fixture()
def setup(tmp_path):
    return make_setup(tmp_path, tmp_path / "scene", tmp_path / "out")


def test_a_second_run_on_a_busy_folder_stops_and_a_killed_run_is_taken_over(setup):
    scene, out, log, env, args = setup
    first = subprocess.Popen([*args, "all"], env=dict(env, SLOW_STAGE="02_smpl_fit"), stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.time() + 60
        while "02_smpl_fit" not in ran(log, 0) and time.time() < deadline:
            time.sleep(0.1)
        second = make(args, env)
        assert second.returncode == 2 and ran(log, 0) == ["01_sfm", "02_smpl_fit"]
        assert re.search(r"out/tiny is in use by pid \d+ on .* \(make all, since .*\); make all needs it alone\. "
                         r"Wait for it to finish, or ask to wait: make WAIT=<seconds>", second.stderr), second.stderr
        direct = subprocess.run([sys.executable, str(REPO / "stages" / "03_masks" / "run.py"), "--scene", str(scene),
                                 "--out", str(out)], env=env, capture_output=True, text=True)
        assert direct.returncode == EXIT_BAD_INPUT and "in use by pid" in direct.stderr  # a stage started by hand waits its turn
        assert len(list((out / "tiny" / ".tmp").iterdir())) == 1  # the live run's folder was left alone
    finally:
        os.killpg(first.pid, signal.SIGKILL)
        first.wait()
    again = make(args, env)
    assert again.returncode == 0, again.stderr
    assert sorted(ran(log, 2)) == sorted(STAGE_NAMES[1:]) and not any((out / "tiny" / ".tmp").iterdir())


STRANGE = "dir with space 'single' \"double\" `touch MARKER` $HOME $(touch MARKER2) é"


def test_paths_with_spaces_quotes_backticks_dollars_and_accents_are_only_paths(tmp_path):
    root = tmp_path / STRANGE
    scene, out, log, env, args = make_setup(tmp_path, root / "scene", root / "out")
    env = dict(env, PWD=str(tmp_path))
    validated = make(args, env, target="validate")
    assert validated.returncode == 0, validated.stderr
    assert make(args, env).returncode == 0 and sorted(ran(log, 0)) == sorted(STAGE_NAMES)
    assert (out / "tiny" / "07_eval" / "manifest.json").is_file()
    cleaned = make(args, env, "STAGE=07_eval", target="clean-stage")
    assert cleaned.returncode == 0 and not (out / "tiny" / "07_eval").exists()
    assert make(args, env, target="03_masks").returncode == 0 and ran(log, len(STAGE_NAMES)) == ["03_masks"]
    assert not list(tmp_path.rglob("MARKER*")) and not list(REPO.glob("MARKER*"))


def test_stamps_follow_content_not_paths_clocks_or_thread_counts(setup, tmp_path):
    scene, out, log, env, args = setup
    assert make(args, env).returncode == 0
    n = len(ran(log, 0))
    moved = tmp_path / "moved scene"
    shutil.move(scene, moved)
    moved_args = [a if not a.startswith("SCENE=") else f"SCENE={moved}" for a in args]
    assert make(moved_args, env).returncode == 0 and ran(log, n) == []  # a moved scene reruns nothing
    assert make(moved_args, env, "PARAMS=compute.threads=1 04_bg_pretrain.checkpoint_every=7").returncode == 0
    assert ran(log, n) == []  # how a stage runs is not what it makes
    frame = moved / "frames" / "000001.png"
    Image.fromarray(np.full((12, 16, 3), 5, np.uint8)).save(frame, compress_level=0)
    assert make(moved_args, env).returncode == 0 and ran(log, n)[0] == "01_sfm"
    n, before = len(ran(log, 0)), frame.stat()
    Image.fromarray(np.full((12, 16, 3), 7, np.uint8)).save(frame, compress_level=0)  # stored: the same size
    os.utime(frame, ns=(before.st_atime_ns, before.st_mtime_ns))  # the same mtime, as cp -p, rsync -t, tar give
    assert frame.stat().st_size == before.st_size and frame.stat().st_mtime_ns == before.st_mtime_ns
    assert make(moved_args, env).returncode == 0 and ran(log, n)[0] == "01_sfm"


def test_an_unwritable_output_folder_and_links_out_of_the_scene_are_refused(setup, tmp_path):
    scene, out, log, env, args = setup
    blocker = tmp_path / "a file"
    blocker.write_text("")
    result = make([a if not a.startswith("OUT=") else f"OUT={blocker / 'runs'}" for a in args], env)
    assert result.returncode == 2 and f"OUT={blocker / 'runs'}: cannot write runs there" in result.stderr
    outside = tmp_path / "elsewhere.png"
    Image.fromarray(np.zeros((12, 16, 3), np.uint8)).save(outside)
    (scene / "frames" / "000002.png").unlink()
    (scene / "frames" / "000002.png").symlink_to(outside)
    violations = validate_scene(scene)
    assert [v.file for v in violations] == ["frames/000002.png"] and "may not point outside" in violations[0].rule
    assert make(args, env).returncode == 2 and ran(log, 0) == []


def test_stage_01_copies_frames_never_links_them(tmp_path):
    from glimpse.cameras.undistort import Undistorter
    from glimpse.scene import load_scene
    from glimpse.sfm.frames import write_frames
    from tests.make_helpers import write_tiny_scene

    write_tiny_scene(tmp_path / "scene")
    scene = load_scene(tmp_path / "scene")
    undistorter = Undistorter(np.eye(3), None, scene.width, scene.height)
    written = write_frames(scene, sorted(scene.frame_paths), undistorter, tmp_path / "frames")
    for fid, path in written.items():
        assert not os.path.samefile(path, scene.frame_paths[fid]) and path.stat().st_nlink == 1


LOAD_KERNELS = "from glimpse.render import composite_cpu as c; print(c.__file__); c.extension()"


def test_the_cpp_kernels_build_once_for_every_checkout_and_a_killed_build_blocks_nothing(tmp_path):
    from glimpse.render import composite_cpu

    library = Path(composite_cpu.extension().__file__)  # built, or found in the machine's cache
    build_lock = library.parent.with_name(library.parent.name + ".lock")
    built_at = library.stat().st_mtime_ns
    checkout = tmp_path / "another checkout"
    shutil.copytree(REPO / "glimpse", checkout / "glimpse", ignore=shutil.ignore_patterns("__pycache__"))
    env = dict(os.environ, PYTHONPATH=str(checkout))
    with exclusive_lock(build_lock, "a build that is killed"):
        (library.parent / "lock").write_text("")  # torch's marker, as a build killed mid-way leaves it
        busy = subprocess.run([sys.executable, "-c", LOAD_KERNELS], env=dict(env, GLIMPSE_BUILD_WAIT_S="0.3"), cwd=tmp_path,
                              capture_output=True, text=True, timeout=120)
        assert busy.returncode != 0 and "LockBusy" in busy.stderr and "building the C++ rasterizer" in busy.stderr
    loaded = subprocess.run([sys.executable, "-c", LOAD_KERNELS], env=env, cwd=tmp_path, capture_output=True, text=True,
                            timeout=120)
    assert loaded.returncode == 0, loaded.stderr
    assert loaded.stdout.startswith(str(checkout))  # the other checkout's code, the same build: nothing rebuilt
    assert library.stat().st_mtime_ns == built_at and not (library.parent / "lock").exists()
