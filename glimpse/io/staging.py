"""Writing so that a reader never sees half a result: a file or a folder is written under a temporary name
beside its destination (same file system) and renamed into place only when complete; on failure the temporary
is removed and whatever was at the destination stays."""

from __future__ import annotations

import os
import shutil
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def staged_file(path: Path) -> Iterator[Path]:
    """A unique hidden path beside ``path`` to write the file to; it replaces ``path`` when the block succeeds.
    (Open it with mode "x": the file then gets the usual permissions, unlike tempfile.mkstemp's 0600.)"""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex}.tmp")
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextmanager
def staged_folder(final: Path) -> Iterator[Path]:
    """A fresh folder beside ``final`` to write into; it replaces ``final`` when the block succeeds."""
    tmp = final.with_name(final.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    shutil.rmtree(final, ignore_errors=True)
    tmp.rename(final)
