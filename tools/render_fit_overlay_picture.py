"""Picture for docs/fitting.md: stage 02's overlay video, frames of the full-size `demo`
fixture fitted from its 2D keypoints only.

    .venv/bin/python tools/render_fit_overlay_picture.py   # writes docs/images/fit_overlay.png
"""

import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from glimpse.config import REPO_ROOT  # noqa: E402
from glimpse.fixtures.scenes import make_scene  # noqa: E402
from glimpse.io.images import write_png  # noqa: E402
from glimpse.io.video import read_mp4  # noqa: E402
from tests.stage_helpers import run  # noqa: E402

SHOWN = {"demo": (20, 45, 70)}  # frames of each scenario's overlay video


def main() -> None:
    tiles = []
    with tempfile.TemporaryDirectory() as tmp:
        for scenario, frames in SHOWN.items():
            scene = make_scene(scenario, Path(tmp) / scenario, "full", seed=0)
            run("01_sfm", scene, Path(tmp) / "out")
            result = run("02_smpl_fit", scene, Path(tmp) / "out", "02_smpl_fit.mode=keypoints2d")
            video = read_mp4(result / "overlay.mp4")
            tiles += [video[f] for f in frames]
    write_png(REPO_ROOT / "docs" / "images" / "fit_overlay.png", np.concatenate(tiles, axis=1))


if __name__ == "__main__":
    main()
