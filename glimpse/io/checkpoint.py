"""Checkpoints of long optimisations, in ``OUT/<scene>/.work/<stage>/`` (CONTRACTS.md).

A checkpoint is one ``torch.save`` file written atomically (a temporary file, then a
rename), so a run killed while saving leaves the previous checkpoint intact. It carries a
fingerprint of everything the run depends on (parameters, upstream manifests): a
checkpoint of another configuration is never resumed, only reported and replaced.

Checkpoints are read with ``torch.load(weights_only=True)``: tensors, numbers, strings and
containers only, never an object whose unpickling could run code (a run folder may come from
someone else). A checkpoint holding anything else is refused and the stage starts afresh.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from pathlib import Path
from typing import Any

import torch

CHECKPOINT_FORMAT = "glimpse-checkpoint/1"
log = logging.getLogger("glimpse")


def fingerprint(*parts: Any) -> str:
    """sha256 of the parts as canonical JSON (dicts, lists, strings, numbers)."""
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()


def save_checkpoint(path: Path, key: str, state: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    torch.save({"format": CHECKPOINT_FORMAT, "fingerprint": key, "state": state}, tmp)
    os.replace(tmp, path)


def load_checkpoint(path: Path, key: str) -> dict[str, Any] | None:
    """The saved state, or None when there is none or it belongs to other inputs or parameters."""
    if not path.is_file():
        return None
    try:
        saved = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # truncated, foreign, or holding objects: start afresh, say why
        log.warning("ignoring unreadable checkpoint %s (%s)", path, exc)
        return None
    if not isinstance(saved, dict) or saved.get("format") != CHECKPOINT_FORMAT:
        log.warning("ignoring checkpoint %s: not %s", path, CHECKPOINT_FORMAT)
        return None
    if saved.get("fingerprint") != key:
        log.info("ignoring checkpoint %s: it was made with other parameters or inputs", path)
        return None
    return saved["state"]
