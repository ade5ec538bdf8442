"""Render docs/images/fixture_people.png: synthetic people (glimpse.fixtures.people) from the front and back.

Usage: .venv/bin/python tools/render_fixture_people.py [output.png]
Each column pair is one look (preset, seed) in a walking frame, seen from 3 m in front and from
3 m behind (the camera at chest height looking horizontally at the pelvis's track).
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from glimpse.body.model import BodyModel  # noqa: E402
from glimpse.body.motion import builtin_motion
from glimpse.fixtures.mesh_render import render_meshes
from glimpse.fixtures.people import dress, person_mesh, pose_person, random_look

MODEL_PATH = ROOT / "glimpse/body/assets/free_body.npz"
OUTPUT = ROOT / "docs/images/fixture_people.png"
LOOKS = ((11, "neutral"), (12, "child"), (13, "heavy"), (14, "woman"), (15, "tall"))
WALK_FRAME = 6  # of builtin_motion("walk", 24, 24)
WIDTH, HEIGHT = 200, 300
FOCAL_PX = 370.0
DISTANCE_M = 3.0
CAMERA_HEIGHT_M = -0.2  # canonical frame: the pelvis is at about -0.24 m
BACKGROUND = (0.93, 0.93, 0.93)
LABEL_COLOUR = (40, 40, 40)


def camera(behind: bool, target: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """K, R, t of a camera DISTANCE_M in front of (+z) or behind (-z) ``target``, looking at it."""
    K = np.array([[FOCAL_PX, 0, (WIDTH - 1) / 2], [0, FOCAL_PX, (HEIGHT - 1) / 2], [0, 0, 1]])
    R = np.diag([-1.0, -1.0, 1.0]) if behind else np.diag([1.0, -1.0, -1.0])
    centre = np.array([target[0], CAMERA_HEIGHT_M, target[2] + (-DISTANCE_M if behind else DISTANCE_M)])
    return K, R, -R @ centre


def main(output: Path = OUTPUT) -> None:
    model = BodyModel.from_file(MODEL_PATH)
    walk = builtin_motion("walk", 24, 24)
    tiles = []
    for seed, preset in LOOKS:
        person = dress(model, random_look(seed, preset), texture_size=1024)
        posed = pose_person(model, person, walk.global_orient[WALK_FRAME], walk.body_pose[WALK_FRAME],
                            walk.transl[WALK_FRAME])[0]
        mesh = person_mesh(person, posed)
        target = walk.transl[WALK_FRAME]
        for behind in (False, True):
            view = render_meshes([mesh], *camera(behind, target), WIDTH, HEIGHT, background=BACKGROUND)
            tile = np.ascontiguousarray((view.rgb[..., ::-1] * 255).round().astype(np.uint8))
            label = f"{preset} #{seed} {'back' if behind else 'front'}"
            cv2.putText(tile, label, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.42, LABEL_COLOUR, 1, cv2.LINE_AA)
            tiles.append(tile)
    output.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(output), np.concatenate(tiles, axis=1))
    print(f"wrote {output}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else OUTPUT)
