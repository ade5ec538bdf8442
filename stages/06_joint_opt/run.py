"""Stage 06_joint_opt: joint human and background optimisation.

Not implemented yet: running it stops the pipeline with a clear message and writes nothing.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from glimpse.pipeline.runner import stage_main  # noqa: E402

if __name__ == "__main__":
    stage_main("06_joint_opt", None, __doc__)
