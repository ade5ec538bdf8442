"""Take BlazePose's two models (Apache-2.0) out of the mediapipe wheel on PyPI, without installing mediapipe.

    python tools/install_blazepose.py DEST      (make models)

Downloads mediapipe==0.10.21's manylinux x86_64 wheel for CPython 3.11 (the same file on every machine; the
models inside do not depend on the platform) into a temporary folder, extracts pose_detection.tflite and
pose_landmark_full.tflite into DEST, checks their SHA-256 and writes DEST/.installed. Nothing else of the
wheel is kept.
"""

from __future__ import annotations

import hashlib
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

WHEEL = "mediapipe==0.10.21"
WHEEL_PLATFORM = ("--platform", "manylinux_2_28_x86_64", "--python-version", "3.11", "--only-binary=:all:")
MODELS = {
    "mediapipe/modules/pose_detection/pose_detection.tflite":
        "9ba9dd3d42efaaba86b4ff0122b06f29c4122e756b329d89dca1e297fd8f866c",
    "mediapipe/modules/pose_landmark/pose_landmark_full.tflite":
        "e9a5c5cb17f736fafd4c2ec1da3b3d331d6edbe8a0d32395855aeb2cdfd64b9f",
}


def main(dest: Path) -> None:
    dest.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", *WHEEL_PLATFORM, "-d", tmp,
                        WHEEL], check=True)
        wheel = next(Path(tmp).glob("mediapipe-*.whl"))
        with zipfile.ZipFile(wheel) as archive:
            for member, sha256 in MODELS.items():
                data = archive.read(member)
                if hashlib.sha256(data).hexdigest() != sha256:
                    raise SystemExit(f"{wheel.name}: {member} does not have the expected SHA-256 {sha256}")
                target = dest / Path(member).name
                partial = target.with_suffix(".partial")
                partial.write_bytes(data)
                partial.replace(target)
    (dest / ".installed").write_text(f"{WHEEL}\n")
    print(f"BlazePose models in {dest}/ (from {WHEEL}, Apache-2.0)")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("models/blazepose"))
