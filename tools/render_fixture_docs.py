"""Pictures for docs/fixtures.md: for each scenario (small size), one input frame and one
held-out frame side by side, with each person's visible mask outlined.

    .venv/bin/python tools/render_fixture_docs.py      # writes docs/images/fixture_<scenario>.png
"""

import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from glimpse.config import REPO_ROOT  # noqa: E402
from glimpse.fixtures.scenes import SCENARIOS, make_scene  # noqa: E402

SCALE = 2  # upscale the small frames for the page


def picture(scene: Path) -> np.ndarray:
    frames = sorted((scene / "frames").glob("*.png"))
    frame = frames[len(frames) // 2]
    image = cv2.imread(str(frame))
    for mask_path in sorted(scene.glob(f"humans/*/masks/{frame.name}")):
        mask = cv2.imread(str(mask_path), cv2.IMREAD_GRAYSCALE)
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        cv2.drawContours(image, contours, -1, (255, 255, 255), 1)
    held_out = sorted((scene / "eval").glob(f"cam*/{frame.name}")) or sorted((scene / "eval").glob("cam*/*.png"))
    other = cv2.imread(str(held_out[0]))
    tile = np.hstack([image, np.full((image.shape[0], 4, 3), 255, np.uint8), other])
    return cv2.resize(tile, None, fx=SCALE, fy=SCALE, interpolation=cv2.INTER_NEAREST)


def main() -> None:
    out = REPO_ROOT / "docs" / "images"
    with tempfile.TemporaryDirectory() as tmp:
        for name in SCENARIOS:
            scene = make_scene(name, Path(tmp) / name, "small", seed=0)
            cv2.imwrite(str(out / f"fixture_{name}.png"), picture(scene))
            print(f"wrote {out / f'fixture_{name}.png'}")


if __name__ == "__main__":
    main()
