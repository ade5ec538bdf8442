"""glimpse.allocator: freed memory stays with the process for the next iteration (glibc), unless the environment
tunes the allocator itself."""

import os
import platform
import subprocess
import sys
from pathlib import Path

import pytest

from glimpse.allocator import USER_SETTINGS, keep_freed_memory

ROOT = Path(__file__).resolve().parents[1]
needs_glibc = pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc",
                                 reason="the allocator settings are glibc's")

# An iteration that allocates three 24 MB blocks (the C library's malloc), writes them and frees them, as a training
# step allocates and frees its buffers: prints the page faults of each iteration after the first.
ITERATIONS = """
import ctypes

libc = ctypes.CDLL(None)
libc.malloc.restype, libc.malloc.argtypes, libc.free.argtypes = ctypes.c_void_p, (ctypes.c_size_t,), (ctypes.c_void_p,)
SIZE = 24 * 2**20

def faults():
    with open("/proc/self/stat") as stat:
        return int(stat.read().rsplit(")", 1)[1].split()[7])  # minflt

counts = []
for _ in range(5):
    before = faults()
    blocks = [libc.malloc(SIZE) for _ in range(3)]
    for block in blocks:
        ctypes.memset(block, 1, SIZE)  # every page written
    for block in blocks:
        libc.free(block)
    counts.append(faults() - before)
print(*counts[1:])
"""


def iteration_faults(first_import: str) -> list[int]:
    env = {k: v for k, v in os.environ.items() if k not in (*USER_SETTINGS, "LD_PRELOAD")}  # glibc's own malloc
    out = subprocess.run([sys.executable, "-c", f"import sys; sys.path.insert(0, {str(ROOT)!r}); {first_import}\n"
                          + ITERATIONS], capture_output=True, text=True, check=True, env=env, cwd=ROOT)
    return [int(n) for n in out.stdout.split()]


@needs_glibc
def test_freed_buffers_are_not_faulted_in_again_once_glimpse_is_imported():
    pages = 3 * 24 * 2**20 // 4096
    plain = iteration_faults("pass")
    # glibc by default gives the 72 MB back (more than its 48 MB trim threshold) and faults it in again every time, a
    # page at a time: where it does not (huge pages for every heap, another allocator), there is nothing to show
    if min(plain) < pages // 2:
        pytest.skip(f"freed blocks are not faulted in again page by page here ({plain} faults an iteration)")
    kept = iteration_faults("import glimpse")
    assert max(kept) < pages // 20, kept


@needs_glibc
@pytest.mark.parametrize("name", USER_SETTINGS)
def test_the_environments_own_allocator_settings_win(monkeypatch, name):
    monkeypatch.setenv(name, "1048576" if name != "GLIBC_TUNABLES" else "glibc.malloc.trim_threshold=1048576")
    assert keep_freed_memory() is False


@needs_glibc
def test_the_settings_are_taken_where_the_environment_gives_none(monkeypatch):
    for name in USER_SETTINGS:
        monkeypatch.delenv(name, raising=False)
    assert keep_freed_memory() is True
