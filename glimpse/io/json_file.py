"""Writing a stage's JSON documents (reports, init records)."""

from __future__ import annotations

import json
from pathlib import Path

JSON_INDENT = 1  # spaces per level: readable, and small for per-frame tables


def write_json(path: Path, doc: dict) -> None:
    """``doc`` as indented JSON with a final newline."""
    path.write_text(json.dumps(doc, indent=JSON_INDENT) + "\n")
