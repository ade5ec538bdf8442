"""Test set-up: import glimpse from this checkout; keep OpenMP polite on shared cores."""

import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO_ROOT))
import glimpse  # noqa: E402,F401  (sets OpenMP's waiting before torch loads it)
