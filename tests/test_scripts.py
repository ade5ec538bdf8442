"""Scripts run as `python bench/x.py` (or tools/, stages/NN/) put their own folder first on sys.path, so a file
there named like a standard-library module replaces it for everything the script imports (a bench/profile.py
once broke every benchmark that let torch import cProfile)."""

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_no_script_folder_shadows_a_standard_library_module():
    folders = [ROOT / "bench", ROOT / "tools", *sorted((ROOT / "stages").iterdir())]
    shadowing = [str(path.relative_to(ROOT)) for folder in folders if folder.is_dir()
                 for path in folder.glob("*.py") if path.stem in sys.stdlib_module_names]
    assert not shadowing, f"rename {shadowing}: they shadow standard-library modules for scripts run beside them"
