"""Stage 02_smpl_fit: fit the body to each person.

Not implemented yet: running it stops the pipeline with a clear message and writes nothing.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from glimpse.pipeline.runner import stage_main  # noqa: E402

if __name__ == "__main__":
    stage_main("02_smpl_fit", None, __doc__)
