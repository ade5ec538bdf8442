"""Exclusive locks on files: one process at a time in a run folder, one build of the C++ kernels.

A lock is ``flock(2)`` on a small file. The kernel releases it when its holder dies, kill -9
included, so a lock is never left stale by a crash; the file itself stays and only says who
held it last (pid, host, since when, what for), which is what a refused caller is told.
Shared filesystems must support flock (NFSv4 does; Lustre needs the ``flock`` mount option).

A process may hand its lock down to the processes it starts (``make`` and the stages under it):
the lock's file descriptor is inherited and named in an environment variable, and a child that
finds its own lock there holds it already (it neither takes nor releases it).
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import socket
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

from glimpse.errors import GlimpseError

# Seconds between two tries while waiting for a lock.
POLL_S = 0.2


class LockBusy(GlimpseError):
    """Another live process holds the lock (and did not let go within the time allowed)."""


@dataclass(frozen=True)
class Holder:
    """Who holds (or last held) a lock: written into the lock file by its holder."""

    pid: int
    host: str
    since: str
    purpose: str

    def describe(self) -> str:
        return f"pid {self.pid} on {self.host} ({self.purpose}, since {self.since})"


def read_holder(lock_file: Path) -> Holder | None:
    """The holder recorded in ``lock_file``; None when it records none (or is unreadable)."""
    try:
        data = json.loads(lock_file.read_text() or "null")
        return Holder(int(data["pid"]), str(data["host"]), str(data["since"]), str(data["purpose"]))
    except (OSError, ValueError, TypeError, KeyError):
        return None


def _inherited(lock_file: Path, env_var: str) -> int | None:
    """The descriptor of ``lock_file``'s lock when an ancestor handed it to this process (named in
    ``env_var``), else None."""
    fd_text = os.environ.get(env_var, "").partition(":")[0]
    if not fd_text.isdigit():
        return None
    fd = int(fd_text)
    try:  # the same file, however its path was spelt
        if not os.path.samestat(os.fstat(fd), os.stat(lock_file)):
            return None
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # shares the ancestor's open file: already ours
    except OSError:
        return None
    return fd


@contextmanager
def exclusive_lock(lock_file: Path, purpose: str, wait_s: float = 0.0, env_var: str | None = None,
                   hint: str = "") -> Iterator[int]:
    """Hold ``lock_file``'s lock for the ``with`` block; yields the lock's file descriptor (to pass to
    child processes).

    purpose:  what the lock is taken for, shown to whoever else asks for it ("make all", "stage 04_bg_pretrain").
    wait_s:   seconds to wait for another holder to let go (0: refuse at once); then LockBusy names it.
    env_var:  hand the lock down to child processes through this environment variable (and accept one
              handed down by an ancestor).
    hint:     what a refused caller can do, appended to LockBusy's message.
    """
    lock_file = Path(lock_file)
    inherited = _inherited(lock_file, env_var) if env_var else None
    if inherited is not None:
        yield inherited
        return
    lock_file.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(lock_file, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        _acquire(fd, lock_file, purpose, wait_s, hint)
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "purpose": purpose,
                                  "since": time.strftime("%Y-%m-%d %H:%M:%S %Z")}).encode(), 0)
        previous = os.environ.get(env_var) if env_var else None
        if env_var:
            os.set_inheritable(fd, True)
            os.environ[env_var] = f"{fd}:{lock_file.absolute()}"
        try:
            yield fd
        finally:
            if env_var:
                if previous is None:
                    os.environ.pop(env_var, None)
                else:
                    os.environ[env_var] = previous
            fcntl.flock(fd, fcntl.LOCK_UN)
    finally:
        os.close(fd)


def _acquire(fd: int, lock_file: Path, purpose: str, wait_s: float, hint: str) -> None:
    deadline, told = time.monotonic() + wait_s, False
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return
        except OSError as exc:
            if exc.errno not in (errno.EAGAIN, errno.EACCES):
                raise GlimpseError(f"{lock_file}: cannot lock ({exc.strerror}); the folder's filesystem must "
                                   f"support flock") from None
        holder = read_holder(lock_file)
        who = holder.describe() if holder else "another process"
        if time.monotonic() >= deadline:
            waited = f" (waited {wait_s:g} s)" if wait_s > 0 else ""
            raise LockBusy(f"{lock_file.parent} is in use by {who}{waited}; {purpose} needs it alone. {hint}".strip())
        if not told:
            print(f"waiting for {who}, which holds {lock_file} (up to {wait_s:g} s)", file=sys.stderr)
            told = True
        time.sleep(POLL_S)


def process_alive(pid: int) -> bool:
    """Whether a process with this pid runs on this machine (a zombie, dead but not yet reaped, does not)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, belongs to someone else
        pass
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()[0]
    except (OSError, IndexError):
        return True
    return state not in ("Z", "X")
