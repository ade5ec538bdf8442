"""The glimpse-scene/1 validator and reader: a tiny valid scene, then one broken rule at a time."""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from glimpse.errors import SceneError
from glimpse.io.images import (
    ImageReadError,
    frame_name,
    parse_frame_name,
    probe_image,
    read_image_header,
    read_mask,
    read_rgb,
    write_png,
)
from glimpse.scene import (
    CameraPose,
    Scene,
    load_scene,
    read_keypoints2d,
    read_keypoints3d,
    validate_scene,
)

try:  # tests/ on sys.path (rootdir-less import mode) or tests as a package
    from scene_builder import (
        EVAL_HEIGHT, EVAL_WIDTH, HEIGHT, WIDTH, build_valid_scene, edit_json, edit_npz, edit_yaml, mask,
        rgb, rotation_y, write_image)
except ImportError:  # pragma: no cover
    from tests.scene_builder import (  # type: ignore[no-redef]
        EVAL_HEIGHT, EVAL_WIDTH, HEIGHT, WIDTH, build_valid_scene, edit_json, edit_npz, edit_yaml, mask,
        rgb, rotation_y, write_image)

Break = Callable[[Path], None]


@pytest.fixture(scope="session")
def template(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The valid scene, written once; tests work on copies."""
    return build_valid_scene(tmp_path_factory.mktemp("template") / "scene")


@pytest.fixture
def scene(template: Path, tmp_path: Path) -> Path:
    """A fresh copy of the valid scene."""
    return Path(shutil.copytree(template, tmp_path / "scene"))


# --- small break helpers ------------------------------------------------------------------------

def yaml_set(**changes: object) -> Break:
    return lambda root: edit_yaml(root / "scene.yaml", lambda doc: doc.update(changes))


def yaml_del(key: str) -> Break:
    return lambda root: edit_yaml(root / "scene.yaml", lambda doc: doc.pop(key))


def json_set(rel: str, keys: tuple[str, ...], value: object) -> Break:
    """Set a nested key of a JSON file; ``value`` may be a function of the old value."""
    def edit(doc: dict) -> None:
        for key in keys[:-1]:
            doc = doc[key]
        doc[keys[-1]] = value(doc.get(keys[-1])) if callable(value) else value
    return lambda root: edit_json(root / rel, edit)


def json_del(rel: str, keys: tuple[str, ...]) -> Break:
    def edit(doc: dict) -> None:
        for key in keys[:-1]:
            doc = doc[key]
        del doc[keys[-1]]
    return lambda root: edit_json(root / rel, edit)


def cams_set(*keys: str, value: object) -> Break:
    return json_set("cameras.json", keys, value)


def eval_set(*keys: str, value: object) -> Break:
    return json_set("eval/cameras.json", ("cameras", "cam1", *keys), value)


def npz_set(rel: str, **changes: object) -> Break:
    return lambda root: edit_npz(root / rel, **changes)


def text(rel: str, content: str = "hello\n") -> Break:
    def write(root: Path) -> None:
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(content)
    return write


def data(rel: str, content: bytes) -> Break:
    return lambda root: (root / rel).write_bytes(content)


def remove(*rels: str) -> Break:
    def rm(root: Path) -> None:
        for rel in rels:
            path = root / rel
            shutil.rmtree(path) if path.is_dir() else path.unlink()
    return rm


def mkdir(rel: str) -> Break:
    return lambda root: (root / rel).mkdir(parents=True)


def image(rel: str, pixels: np.ndarray, **save_args: object) -> Break:
    return lambda root: write_image(root / rel, pixels, **save_args) and None


def rename(src: str, dst: str) -> Break:
    return lambda root: (root / src).rename(root / dst) and None


def truncate(rel: str) -> Break:
    def cut(root: Path) -> None:
        content = (root / rel).read_bytes()
        (root / rel).write_bytes(content[: len(content) // 2])
    return cut


def both(*breaks: Break) -> Break:
    def apply(root: Path) -> None:
        for b in breaks:
            b(root)
    return apply


def png16(rel: str, shape: tuple[int, ...]) -> Break:
    """A 16-bit PNG (grey or RGB) written by OpenCV."""
    return lambda root: cv2.imwrite(str(root / rel), np.full(shape, 40000, np.uint16)) and None


def tiff_as(rel: str) -> Break:
    def write(root: Path) -> None:
        Image.fromarray(rgb(WIDTH, HEIGHT)).save(root / rel, format="TIFF")
    return write


def pickled_npz(rel: str) -> Break:
    def write(root: Path) -> None:
        np.savez(root / rel, frame_ids=np.array([0, 1, 2]), betas=np.array([{"a": 1}], dtype=object))
    return write


def npy_as(rel: str) -> Break:
    def write(root: Path) -> None:
        with open(root / rel, "wb") as handle:
            np.save(handle, np.zeros(3))
    return write


def only_3d_file(keep: str) -> Break:
    """Remove every smpl.npz / keypoints3d.npz except ``keep``."""
    def strip(root: Path) -> None:
        for path in [*root.glob("humans/*/smpl.npz"), *root.glob("humans/*/keypoints3d.npz")]:
            if path.relative_to(root).as_posix() != keep:
                path.unlink()
    return strip


REFLECTION = np.diag([1.0, 1.0, -1.0]).tolist()
SCALED = (rotation_y(0.05) * 1.1).tolist()
T3 = 3
M = (HEIGHT, WIDTH)


def kp2d(layout: str = "coco17", joints: int = 17, conf: float = 0.9, nan: bool = False) -> dict:
    keypoints = np.full((T3, joints, 3), conf)
    if nan:
        keypoints[1, 2, 0] = np.nan
    return {"layout": np.array(layout), "keypoints": keypoints}


# (break, file, rule fragment, found fragment)
CASES = [
    # scene.yaml
    pytest.param(remove("scene.yaml"), "scene.yaml", "must exist", "no such file", id="yaml-missing"),
    pytest.param(text("scene.yaml", "format: [unclosed\n"), "scene.yaml", "valid YAML", "line", id="yaml-invalid"),
    pytest.param(text("scene.yaml", "- a\n- b\n"), "scene.yaml", "mapping", "list", id="yaml-list"),
    pytest.param(text("scene.yaml", ""), "scene.yaml", "mapping", "empty", id="yaml-empty"),
    pytest.param(yaml_del("format"), "scene.yaml", 'format must be "glimpse-scene/1"', "no", id="format-missing"),
    pytest.param(yaml_set(format="glimpse-scene/2"), "scene.yaml", 'format must be "glimpse-scene/1"',
                 "known versions: glimpse-scene/1", id="format-version"),
    pytest.param(yaml_del("name"), "scene.yaml", "name must be", 'no "name"', id="name-missing"),
    pytest.param(yaml_set(name="my scene/x"), "scene.yaml", "name must be", "my scene/x", id="name-chars"),
    pytest.param(yaml_set(name=""), "scene.yaml", "name must be", '""', id="name-empty"),
    pytest.param(yaml_set(name=".."), "scene.yaml", "name must be", "..", id="name-dots"),
    pytest.param(yaml_set(name=2024), "scene.yaml", "name must be", "2024", id="name-number"),
    pytest.param(yaml_del("fps"), "scene.yaml", "fps must be a positive finite number", "no", id="fps-missing"),
    pytest.param(yaml_set(fps=0), "scene.yaml", "fps must be a positive", "0", id="fps-zero"),
    pytest.param(yaml_set(fps=-30), "scene.yaml", "fps must be a positive", "-30", id="fps-negative"),
    pytest.param(yaml_set(fps=float("nan")), "scene.yaml", "fps must be", "NaN", id="fps-nan"),
    pytest.param(yaml_set(fps=float("inf")), "scene.yaml", "fps must be", "Infinity", id="fps-inf"),
    pytest.param(yaml_set(fps="30/1"), "scene.yaml", "fps must be", '"30/1"', id="fps-string"),
    pytest.param(yaml_set(fps=10**400), "scene.yaml", "fps must be", "1000", id="fps-huge"),
    pytest.param(yaml_set(fps=True), "scene.yaml", "fps must be", "true", id="fps-bool"),
    pytest.param(yaml_set(camera_motion="panning"), "scene.yaml", "camera_motion must be one of static | moving",
                 "panning", id="camera-motion"),
    pytest.param(yaml_set(body_model="smplx"), "scene.yaml", "body_model must be one of free | smpl", "smplx",
                 id="body-model"),
    pytest.param(yaml_set(overrides=[1, 2]), "scene.yaml", "overrides must be a mapping", "list", id="overrides-list"),
    pytest.param(yaml_set(overrides={"04_bg_pretrain": 5}), "scene.yaml", "overrides must be a mapping",
                 "04_bg_pretrain", id="overrides-entry"),
    pytest.param(yaml_set(notes="hi"), "scene.yaml", "may only have the keys format, name, fps", '"notes"',
                 id="yaml-unknown-key"),
    # frames/ and video.mp4
    pytest.param(remove("frames"), "frames/", "exactly one of frames/ and video.mp4", "neither", id="no-frames"),
    pytest.param(data("video.mp4", b"junk"), "frames/", "exactly one of frames/ and video.mp4", "both",
                 id="frames-and-video"),
    pytest.param(both(remove("frames"), text("frames")), "frames", "frames/ must be a folder", "a file",
                 id="frames-file"),
    pytest.param(text("frames/notes.txt"), "frames/notes.txt", "frames/ may only hold", "a file", id="frame-stray"),
    pytest.param(image("frames/42.png", rgb(WIDTH, HEIGHT)), "frames/42.png", "frames/ may only hold", "",
                 id="frame-short-name"),
    pytest.param(image("frames/0000003.png", rgb(WIDTH, HEIGHT)), "frames/0000003.png", "frames/ may only hold",
                 "", id="frame-7-digits"),
    pytest.param(image("frames/000003.PNG", rgb(WIDTH, HEIGHT)), "frames/000003.PNG", "frames/ may only hold",
                 "", id="frame-uppercase-suffix"),
    pytest.param(mkdir("frames/sub"), "frames/sub/", "frames/ may only hold", "a folder", id="frame-subfolder"),
    pytest.param(remove("frames/000000.png", "frames/000001.png", "frames/000002.png"), "frames/",
                 "at least one frame", "no frame", id="frames-empty"),
    pytest.param(image("frames/000001.jpg", rgb(WIDTH, HEIGHT)), "frames/000001.png", "appear once",
                 "000001.jpg and 000001.png", id="frame-duplicate-id"),
    pytest.param(truncate("frames/000001.png"), "frames/000001.png", "decodes completely", "truncated",
                 id="frame-truncated"),
    pytest.param(text("frames/000001.png", "not an image"), "frames/000001.png", "decodes completely", "",
                 id="frame-not-image"),
    pytest.param(png16("frames/000001.png", (HEIGHT, WIDTH, 3)), "frames/000001.png", "8-bit", "16-bit",
                 id="frame-rgb16"),
    pytest.param(png16("frames/000001.png", (HEIGHT, WIDTH)), "frames/000001.png", "8-bit", "16-bit",
                 id="frame-grey16"),
    pytest.param(tiff_as("frames/000001.png"), "frames/000001.png", "PNG or JPEG", "TIFF", id="frame-tiff"),
    pytest.param(image("frames/000001.png", rgb(20, HEIGHT)), "frames/000001.png",
                 "every frame must have the same size", "20x12, the others are 16x12", id="frame-size"),
    pytest.param(both(remove("frames"), data("video.mp4", b"\x00" * 64)), "video.mp4", "OpenCV", "",
                 id="video-corrupt"),
    # cameras.json
    pytest.param(text("cameras.json", "{"), "cameras.json", "valid JSON", "line 1", id="cams-json"),
    pytest.param(text("cameras.json", "[]"), "cameras.json", "JSON object", "list", id="cams-list"),
    pytest.param(both(remove("cameras.json"), mkdir("cameras.json")), "cameras.json", "JSON file", "folder",
                 id="cams-folder"),
    pytest.param(cams_set("format", value="glimpse-cameras/2"), "cameras.json", 'format must be "glimpse-cameras/1"',
                 "glimpse-cameras/2", id="cams-format"),
    pytest.param(json_del("cameras.json", ("format",)), "cameras.json", "format must be", "no", id="cams-no-format"),
    pytest.param(json_del("cameras.json", ("K",)), "cameras.json", "must have the keys width, height, K", '"K"',
                 id="cams-no-K"),
    pytest.param(cams_set("fov", value=60), "cameras.json", "may only have the keys format, width, height, K",
                 '"fov"', id="cams-unknown-key"),
    pytest.param(cams_set("width", value=16.0), "cameras.json", "width must be a positive integer", "16",
                 id="cams-width-float"),
    pytest.param(cams_set("height", value=0), "cameras.json", "height must be a positive integer", "0",
                 id="cams-height-zero"),
    pytest.param(cams_set("width", value=32), "cameras.json", "must equal the frame size 16x12", "32x12",
                 id="cams-size"),
    pytest.param(cams_set("K", value=[[20, 0, 7.5], [0, 20, 5.5]]), "cameras.json", "K must be a 3x3 matrix",
                 "K has 2 entries", id="K-shape"),
    pytest.param(cams_set("K", value=lambda K: [[float("nan"), *K[0][1:]], *K[1:]]), "cameras.json",
                 "K must be a 3x3 matrix of finite numbers", "K[0][0] = NaN", id="K-nan"),
    pytest.param(cams_set("K", value=lambda K: [K[0][:2] + ["7.5"], *K[1:]]), "cameras.json",
                 "K must be a 3x3 matrix", 'K[0][2] = "7.5"', id="K-string"),
    pytest.param(cams_set("K", value=lambda K: [[-20, *K[0][1:]], *K[1:]]), "cameras.json", "fx > 0 and fy > 0",
                 "fx = -20", id="K-fx"),
    pytest.param(cams_set("K", value=lambda K: [[K[0][0], 0.5, K[0][2]], *K[1:]]), "cameras.json", "zero skew",
                 "K[0][1] = 0.5", id="K-skew"),
    pytest.param(cams_set("K", value=lambda K: [*K[:2], [0, 0, 2]]), "cameras.json", "last row [0, 0, 1]",
                 "[0, 0, 2]", id="K-last-row"),
    pytest.param(cams_set("K", value=lambda K: [K[0], [1, *K[1][1:]], K[2]]), "cameras.json", "K[1][0] = 0",
                 "K[1][0] = 1", id="K-lower"),
    pytest.param(cams_set("dist", value=[0.1, 0.2, 0.3]), "cameras.json", "dist must be a list of 4 or 5",
                 "3 entries", id="dist-length"),
    pytest.param(cams_set("dist", value=[float("inf"), 0, 0, 0]), "cameras.json", "dist must be a list of 4 or 5",
                 "dist[0] = Infinity", id="dist-inf"),
    pytest.param(cams_set("frames", value=[]), "cameras.json", "frames must be an object", "list",
                 id="frames-list"),
    pytest.param(cams_set("frames", "1", value={"R": np.eye(3).tolist(), "t": [0, 0, 0]}), "cameras.json",
                 "frames keys must be 6-digit frame ids", '"1"', id="pose-key-name"),
    pytest.param(cams_set("frames", "000009", value={"R": np.eye(3).tolist(), "t": [0, 0, 0]}), "cameras.json",
                 "frames keys must be frame ids of the scene", '"000009"', id="pose-key-unknown-frame"),
    pytest.param(cams_set("frames", "000001", "R", value=REFLECTION), "cameras.json",
                 'frames["000001"].R must be a rotation (orthonormal, det +1)', "det = -1.000", id="pose-reflection"),
    pytest.param(cams_set("frames", "000001", "R", value=SCALED), "cameras.json",
                 'frames["000001"].R must be a rotation', "|R R^T - I|", id="pose-scaled"),
    pytest.param(cams_set("frames", "000001", "R", value=[[1, 0, 0], [0, 1, 0], [0, 0, None]]), "cameras.json",
                 'frames["000001"].R must be a 3x3 matrix', "R[2][2] = null", id="pose-R-null"),
    pytest.param(cams_set("frames", "000001", "t", value=[0, 0]), "cameras.json",
                 'frames["000001"].t must be a list of 3 finite numbers', "2 entries", id="pose-t-length"),
    pytest.param(json_del("cameras.json", ("frames", "000001", "t")), "cameras.json",
                 'frames["000001"] must have the keys R, t', '"t"', id="pose-no-t"),
    pytest.param(cams_set("frames", "000001", "rot", value=1), "cameras.json",
                 'frames["000001"] may only have the keys R, t, K', '"rot"', id="pose-unknown-key"),
    pytest.param(cams_set("frames", "000002", "K", value=lambda K: [K[0], [0, 0, K[1][2]], K[2]]), "cameras.json",
                 'frames["000002"].K must have fx > 0 and fy > 0', "fy = 0", id="pose-K"),
    pytest.param(cams_set("frames", "000001", value=[1, 2]), "cameras.json", 'frames["000001"] must be an object',
                 "list", id="pose-not-object"),
    # humans/
    pytest.param(text("humans/readme.txt"), "humans/readme.txt", "humans/ may only hold person folders", "a file",
                 id="humans-stray"),
    pytest.param(both(remove("humans", "eval/cam1/masks/p0"), text("humans")), "humans", "humans/ must be a folder",
                 "a file", id="humans-file"),
    pytest.param(rename("humans/p1", "humans/p 1"), "humans/p 1/", "person folder must be named", '"p 1"',
                 id="pid-space"),
    pytest.param(rename("humans/p1", "humans/union"), "humans/union/", 'not "union"', '"union"', id="pid-union"),
    pytest.param(text("humans/p0/notes.txt"), "humans/p0/notes.txt", "a person folder may only hold smpl.npz",
                 "a file", id="person-stray"),
    pytest.param(both(remove("humans/p1/masks"), text("humans/p1/masks")), "humans/p1/masks",
                 "a person folder may only hold", "it must be a folder", id="person-masks-file"),
    pytest.param(mkdir("humans/p2"), "humans/p2/", "a person must have data", "none", id="person-no-data"),
    pytest.param(mkdir("humans/p2/masks"), "humans/p2/", "a person must have data", "none",
                 id="person-empty-masks"),
    pytest.param(data("humans/p0/smpl.npz", b"garbage"), "humans/p0/smpl.npz", "allow_pickle=False", "",
                 id="npz-corrupt"),
    pytest.param(pickled_npz("humans/p0/smpl.npz"), "humans/p0/smpl.npz", "allow_pickle=False", "",
                 id="npz-pickle"),
    pytest.param(npy_as("humans/p0/smpl.npz"), "humans/p0/smpl.npz", "allow_pickle=False", ".npy",
                 id="npz-is-npy"),
    pytest.param(npz_set("humans/p0/smpl.npz", betas=None), "humans/p0/smpl.npz", "must have the arrays frame_ids",
                 '"betas"', id="smpl-no-betas"),
    pytest.param(npz_set("humans/p0/smpl.npz", betas=np.zeros(11)), "humans/p0/smpl.npz",
                 "betas must be a numeric array of shape (10,)", "(11,)", id="smpl-betas"),
    pytest.param(npz_set("humans/p0/smpl.npz", body_pose=np.zeros((2, 69))), "humans/p0/smpl.npz",
                 "body_pose must be a numeric array of shape (T, 69) with T = 3", "(2, 69)", id="smpl-T"),
    pytest.param(npz_set("humans/p0/smpl.npz", global_orient=np.full((3, 3), "a")), "humans/p0/smpl.npz",
                 "global_orient must be a numeric array", "<U1", id="smpl-strings"),
    pytest.param(npz_set("humans/p0/smpl.npz", transl=np.array([[0, 0, np.nan]] * 3)), "humans/p0/smpl.npz",
                 "transl must hold only finite numbers", "(0, 2)", id="smpl-nan"),
    pytest.param(npz_set("humans/p0/smpl.npz", frame_ids=np.array([0.0, 1.0, 2.0])), "humans/p0/smpl.npz",
                 "frame_ids must be a 1-D integer array", "float64", id="smpl-ids-float"),
    pytest.param(npz_set("humans/p0/smpl.npz", frame_ids=np.zeros(0, int), global_orient=np.zeros((0, 3)),
                         body_pose=np.zeros((0, 69)), transl=np.zeros((0, 3))), "humans/p0/smpl.npz",
                 "at least one id", "(0,)", id="smpl-empty"),
    pytest.param(npz_set("humans/p0/smpl.npz", frame_ids=np.array([0, 1, 1])), "humans/p0/smpl.npz",
                 "frame_ids must be unique", "000001", id="smpl-ids-dup"),
    pytest.param(npz_set("humans/p0/smpl.npz", frame_ids=np.array([0, 1, 7])), "humans/p0/smpl.npz",
                 "frame_ids must be frame ids of the scene", "000007", id="smpl-ids-unknown"),
    pytest.param(npz_set("humans/p0/keypoints2d.npz", layout=np.array("body25")), "humans/p0/keypoints2d.npz",
                 "layout must be one of coco17 (17 joints), openpose25 (25 joints)", "body25", id="kp2d-layout"),
    pytest.param(npz_set("humans/p0/keypoints2d.npz", layout=np.array(["coco17"])), "humans/p0/keypoints2d.npz",
                 "layout must be a scalar string", "(1,)", id="kp2d-layout-array"),
    pytest.param(npz_set("humans/p0/keypoints2d.npz", layout=None), "humans/p0/keypoints2d.npz",
                 "must have the arrays frame_ids, layout, keypoints", '"layout"', id="kp2d-no-layout"),
    pytest.param(npz_set("humans/p0/keypoints2d.npz", **kp2d("openpose25", 17)), "humans/p0/keypoints2d.npz",
                 "keypoints must be a numeric array of shape (T, J, 3) with T = 3, J = 25", "(3, 17, 3)",
                 id="kp2d-joints"),
    pytest.param(npz_set("humans/p0/keypoints2d.npz", **kp2d(conf=1.5)), "humans/p0/keypoints2d.npz",
                 "confidence (the last channel) must be in [0, 1]", "1.5", id="kp2d-confidence"),
    pytest.param(npz_set("humans/p0/keypoints2d.npz", **kp2d(nan=True)), "humans/p0/keypoints2d.npz",
                 "keypoints must hold only finite numbers", "(1, 2, 0)", id="kp2d-nan"),
    pytest.param(npz_set("humans/p0/keypoints2d.npz", relative3d=np.zeros((3, 17, 3))), "humans/p0/keypoints2d.npz",
                 "relative3d must be a numeric array of shape (T, J, 4)", "(3, 17, 3)", id="kp2d-relative3d-shape"),
    pytest.param(npz_set("humans/p0/keypoints2d.npz", relative3d=np.full((3, 17, 4), 2.0)),
                 "humans/p0/keypoints2d.npz", "relative3d confidence", "2", id="kp2d-relative3d-confidence"),
    pytest.param(npz_set("humans/p1/keypoints3d.npz", joints=np.zeros((3, 25, 3))), "humans/p1/keypoints3d.npz",
                 "joints must be a numeric array of shape (T, J, 4)", "(3, 25, 3)", id="kp3d-shape"),
    pytest.param(npz_set("humans/p1/keypoints3d.npz", joints=np.full((3, 25, 4), -0.5)),
                 "humans/p1/keypoints3d.npz", "joints confidence", "-0.5", id="kp3d-confidence"),
    pytest.param(both(remove("cameras.json"), only_3d_file("humans/p0/smpl.npz")), "humans/p0/smpl.npz",
                 "a moving camera with no per-frame poses in cameras.json can only carry 2D person data",
                 "no cameras.json", id="moving-no-cameras"),
    pytest.param(both(json_del("cameras.json", ("frames",)), only_3d_file("humans/p1/keypoints3d.npz")),
                 "humans/p1/keypoints3d.npz", "can only carry 2D person data", "cameras.json without per-frame poses",
                 id="moving-no-poses"),
    pytest.param(image("humans/p0/masks/mask1.png", mask(*M[::-1])), "humans/p0/masks/mask1.png",
                 "masks/ may only hold masks named", "a file", id="mask-name"),
    pytest.param(image("humans/p0/masks/000001.jpg", mask(*M[::-1])), "humans/p0/masks/000001.jpg",
                 "masks/ may only hold masks named", "a file", id="mask-jpg-name"),
    pytest.param(mkdir("humans/p0/masks/extra"), "humans/p0/masks/extra/", "masks/ may only hold", "a folder",
                 id="mask-folder"),
    pytest.param(image("humans/p0/masks/000009.png", mask(*M[::-1])), "humans/p0/masks/000009.png",
                 "a mask's frame id must be a frame of the scene", "000000..000002", id="mask-unknown-frame"),
    pytest.param(image("humans/p0/masks/000001.png", rgb(*M[::-1])), "humans/p0/masks/000001.png",
                 "single-channel 8-bit", "RGB", id="mask-rgb"),
    pytest.param(png16("humans/p0/masks/000001.png", M), "humans/p0/masks/000001.png", "single-channel 8-bit",
                 "16-bit", id="mask-16bit"),
    pytest.param(image("humans/p0/masks/000001.png", mask(*M[::-1]), format="JPEG"), "humans/p0/masks/000001.png",
                 "single-channel PNG", "JPEG", id="mask-jpeg-data"),
    pytest.param(image("humans/p0/masks/000001.png", mask(*M[::-1]) // 2), "humans/p0/masks/000001.png",
                 "only the values 0 and 255", "127", id="mask-values"),
    pytest.param(image("humans/p0/masks/000001.png", mask(20, 12)), "humans/p0/masks/000001.png",
                 "a mask must have the frame size 16x12", "20x12", id="mask-size"),
    pytest.param(truncate("humans/p0/masks/000001.png"), "humans/p0/masks/000001.png", "decodes completely", "",
                 id="mask-truncated"),
    pytest.param(text("humans/p0/reference/notes.txt"), "humans/p0/reference/notes.txt",
                 "reference/ may only hold .png, .jpg or .jpeg", "a file", id="reference-stray"),
    pytest.param(mkdir("humans/p0/reference/more"), "humans/p0/reference/more/", "reference/ may only hold",
                 "a folder", id="reference-folder"),
    pytest.param(text("humans/p0/reference/side.jpg", "xx"), "humans/p0/reference/side.jpg", "decodes completely",
                 "", id="reference-corrupt"),
    # eval/
    pytest.param(remove("eval/cameras.json"), "eval/cameras.json", "eval/ must have eval/cameras.json",
                 "no such file", id="eval-no-json"),
    pytest.param(both(remove("eval"), text("eval")), "eval", "eval/ must be a folder", "a file", id="eval-file"),
    pytest.param(text("eval/cameras.json", "{,}"), "eval/cameras.json", "valid JSON", "", id="eval-json"),
    pytest.param(json_set("eval/cameras.json", ("format",), "glimpse-cameras/1"), "eval/cameras.json",
                 'format must be "glimpse-eval-cameras/1"', "glimpse-cameras/1", id="eval-format"),
    pytest.param(json_set("eval/cameras.json", ("extra",), 1), "eval/cameras.json",
                 "may only have the keys format, cameras", '"extra"', id="eval-unknown-key"),
    pytest.param(json_set("eval/cameras.json", ("cameras",), {}), "eval/cameras.json",
                 "cameras must be a non-empty object", "0 key", id="eval-no-cameras"),
    pytest.param(json_set("eval/cameras.json", ("cameras",), lambda cams: {**cams, "cam 2": cams["cam1"]}),
                 "eval/cameras.json", "camera names must be letters, digits", '"cam 2"', id="eval-camera-name"),
    pytest.param(json_del("eval/cameras.json", ("cameras", "cam1", "width")), "eval/cameras.json",
                 'cameras["cam1"] must have the keys K, R, t, width, height', '"width"', id="eval-no-width"),
    pytest.param(eval_set("fov", value=1), "eval/cameras.json", 'cameras["cam1"] may only have the keys', '"fov"',
                 id="eval-unknown-camera-key"),
    pytest.param(eval_set("R", value=REFLECTION), "eval/cameras.json", 'cameras["cam1"].R must be a rotation',
                 "det = -1.000", id="eval-R"),
    pytest.param(eval_set("K", value=lambda K: [[K[0][0], 1.0, K[0][2]], *K[1:]]), "eval/cameras.json",
                 'cameras["cam1"].K must have zero skew', "= 1", id="eval-K"),
    pytest.param(eval_set("t", value=[0, "x", 0]), "eval/cameras.json", 'cameras["cam1"].t must be a list of 3',
                 't[1] = "x"', id="eval-t"),
    pytest.param(eval_set("width", value=-1), "eval/cameras.json", 'cameras["cam1"].width must be a positive integer',
                 "-1", id="eval-width"),
    pytest.param(eval_set("frames", "000000", "R", value=REFLECTION), "eval/cameras.json",
                 'cameras["cam1"].frames["000000"].R must be a rotation', "det = -1.000", id="eval-pose"),
    pytest.param(eval_set("frames", "000009", value={"R": np.eye(3).tolist(), "t": [0, 0, 0]}), "eval/cameras.json",
                 'cameras["cam1"].frames keys must be frame ids of the scene', "000009", id="eval-pose-frame"),
    pytest.param(json_set("eval/cameras.json", ("cameras", "cam1"), None), "eval/cameras.json",
                 'cameras["cam1"] must be an object', "null", id="eval-camera-null"),
    pytest.param(json_set("eval/cameras.json", ("cameras",), lambda cams: {**cams, "cam2": cams["cam1"]}),
                 "eval/cam2/", "must have a folder eval/<cam>/", "no such folder", id="eval-camera-folder"),
    pytest.param(mkdir("eval/cam9"), "eval/cam9/", "must be a camera listed in eval/cameras.json", '"cam9"',
                 id="eval-unlisted-folder"),
    pytest.param(text("eval/notes.txt"), "eval/notes.txt", "eval/ may only hold cameras.json", "a file",
                 id="eval-stray"),
    pytest.param(text("eval/cam1/notes.txt"), "eval/cam1/notes.txt", "eval/cam1/ may only hold images", "a file",
                 id="eval-cam-stray"),
    pytest.param(image("eval/cam1/000001.jpg", rgb(EVAL_WIDTH, EVAL_HEIGHT)), "eval/cam1/000001.png",
                 "appear once in eval/cam1/", "000001.jpg and 000001.png", id="eval-duplicate-image"),
    pytest.param(both(image("eval/cam1/000009.png", rgb(EVAL_WIDTH, EVAL_HEIGHT)),
                      image("eval/cam1/masks/000009.png", mask(EVAL_WIDTH, EVAL_HEIGHT))),
                 "eval/cam1/000009.png", "an eval image's frame id must be a frame of the scene", "000009",
                 id="eval-image-frame"),
    pytest.param(image("eval/cam1/000001.png", rgb(WIDTH, HEIGHT)), "eval/cam1/000001.png",
                 "camera's size 20x10", "16x12", id="eval-image-size"),
    pytest.param(truncate("eval/cam1/000001.png"), "eval/cam1/000001.png", "decodes completely", "",
                 id="eval-image-truncated"),
    pytest.param(remove("eval/cam1/000000.png", "eval/cam1/000001.png", "eval/cam1/000002.png", "eval/cam1/masks"),
                 "eval/cam1/", "at least one image", "no images", id="eval-no-images"),
    pytest.param(remove("eval/cam1/masks/000001.png"), "eval/cam1/masks/",
                 "must have a union mask eval/cam1/masks/<id>.png", "000001", id="eval-missing-mask"),
    pytest.param(image("eval/cam1/masks/000005.png", mask(EVAL_WIDTH, EVAL_HEIGHT)), "eval/cam1/masks/000005.png",
                 "a union mask must have an image with the same frame id", "000005", id="eval-extra-mask"),
    pytest.param(text("eval/cam1/masks/notes.txt"), "eval/cam1/masks/notes.txt", "masks/ may only hold union masks",
                 "a file", id="eval-masks-stray"),
    pytest.param(image("eval/cam1/masks/000001.png", mask(WIDTH, HEIGHT)), "eval/cam1/masks/000001.png",
                 "an eval mask must have its camera's size 20x10", "16x12", id="eval-mask-size"),
    pytest.param(image("eval/cam1/masks/000001.png", np.full((EVAL_HEIGHT, EVAL_WIDTH), 3, np.uint8)),
                 "eval/cam1/masks/000001.png", "only the values 0 and 255", "3", id="eval-mask-values"),
    pytest.param(rename("eval/cam1/masks/p0", "eval/cam1/masks/p9"), "eval/cam1/masks/p9/",
                 "must name a person of humans/", '"p9" (the persons are: p0, p1)', id="eval-person-unknown"),
    pytest.param(image("eval/cam1/masks/p0/000005.png", mask(EVAL_WIDTH, EVAL_HEIGHT)),
                 "eval/cam1/masks/p0/000005.png", "one of the image ids of eval/cam1/", "000005",
                 id="eval-person-mask-frame"),
    pytest.param(text("eval/cam1/masks/p0/notes.txt"), "eval/cam1/masks/p0/notes.txt",
                 "masks/<pid>/ may only hold masks", "a file", id="eval-person-mask-stray"),
    pytest.param(image("eval/cam1/masks/p0/000001.png", rgb(EVAL_WIDTH, EVAL_HEIGHT)),
                 "eval/cam1/masks/p0/000001.png", "single-channel 8-bit", "RGB", id="eval-person-mask-rgb"),
]


def test_valid_scene_has_no_violations(scene: Path) -> None:
    assert validate_scene(scene) == []


@pytest.mark.parametrize(("breaks", "file", "rule", "found"), CASES)
def test_each_rule(scene: Path, breaks: Break, file: str, rule: str, found: str) -> None:
    breaks(scene)
    violations = validate_scene(scene)
    assert len(violations) == 1, "\n".join(str(v) for v in violations)
    (violation,) = violations
    assert violation.file == file, str(violation)
    assert rule in violation.rule, str(violation)
    assert found in violation.found, str(violation)


VALID_VARIANTS = [
    pytest.param(both(remove("cameras.json"), yaml_set(camera_motion="static")), id="static-no-cameras-3d"),
    pytest.param(both(json_del("cameras.json", ("frames",)), yaml_set(camera_motion="unknown")),
                 id="unknown-motion-no-poses-3d"),
    pytest.param(both(remove("cameras.json"), remove("humans/p0/smpl.npz", "humans/p0/keypoints3d.npz",
                                                      "humans/p1/smpl.npz", "humans/p1/keypoints3d.npz")),
                 id="moving-no-cameras-2d-only"),
    pytest.param(cams_set("dist", value=[0.1, 0.0, 0.0, 0.0, 0.01]), id="dist-5"),
    pytest.param(json_del("cameras.json", ("dist",)), id="no-dist"),
    pytest.param(remove("eval"), id="no-eval"),
    pytest.param(remove("humans", "eval/cam1/masks/p0"), id="no-humans"),
    pytest.param(both(yaml_del("camera_motion"), yaml_del("body_model"), yaml_del("overrides")), id="defaults"),
    pytest.param(yaml_set(overrides=None), id="overrides-empty-block"),
    pytest.param(both(text("README.md"), mkdir("notes"), text("notes/a.txt")), id="root-extras-ignored"),
    pytest.param(both(remove("frames/000001.png"), image("frames/000001.jpg", rgb(WIDTH, HEIGHT))), id="jpeg-frame"),
    pytest.param(image("frames/000001.png", rgb(WIDTH, HEIGHT)[..., 0]), id="grey-frame"),
    pytest.param(image("frames/000001.png", np.dstack([rgb(WIDTH, HEIGHT), np.full(M, 255, np.uint8)])),
                 id="rgba-frame"),
    pytest.param(lambda root: Image.fromarray(mask(WIDTH, HEIGHT)).convert("1").save(
        root / "humans/p0/masks/000001.png"), id="bilevel-mask"),
    pytest.param(remove("humans/p1/smpl.npz", "humans/p1/keypoints2d.npz", "humans/p1/keypoints3d.npz"),
                 id="person-masks-only"),
    pytest.param(remove("humans/p1/masks", "humans/p1/reference"), id="person-npz-only"),
    pytest.param(image("humans/p0/reference/IMG_0001.JPG", rgb(30, 40)), id="reference-any-size-upper-suffix"),
    pytest.param(remove("eval/cam1/masks/p0"), id="eval-no-person-masks"),
    pytest.param(remove("eval/cam1/masks"), id="eval-no-masks-full-frame-only"),
    pytest.param(npz_set("humans/p0/smpl.npz", extra=np.zeros(2)), id="smpl-extra-key"),
    pytest.param(yaml_set(fps=29.97, name="Scene-1.v2"), id="float-fps"),
]


@pytest.mark.parametrize("change", VALID_VARIANTS)
def test_valid_variants(scene: Path, change: Break) -> None:
    change(scene)
    assert validate_scene(scene) == []


def test_several_problems_are_listed_together(scene: Path) -> None:
    yaml_set(fps=-1)(scene)
    text("frames/notes.txt")(scene)
    cams_set("frames", "000001", "R", value=REFLECTION)(scene)
    image("humans/p1/masks/000002.png", rgb(WIDTH, HEIGHT))(scene)
    remove("eval/cam1/masks/000000.png")(scene)
    with pytest.raises(SceneError) as caught:
        load_scene(scene)
    files = sorted(v.file for v in caught.value.violations)
    assert files == ["cameras.json", "eval/cam1/masks/", "frames/notes.txt", "humans/p1/masks/000002.png",
                     "scene.yaml"]
    message = str(caught.value)
    assert "5 problem(s)" in message
    assert 'cameras.json: frames["000001"].R must be a rotation (orthonormal, det +1); found det = -1.000' in message


def test_missing_scene_folder(tmp_path: Path) -> None:
    (violation,) = validate_scene(tmp_path / "nope")
    assert violation.found == "no such folder"


def test_load_valid_scene(scene: Path) -> None:
    loaded = load_scene(scene)
    assert isinstance(loaded, Scene)
    assert (loaded.name, loaded.fps, loaded.camera_motion, loaded.body_model) == ("tiny_scene", 10.0, "moving", "smpl")
    assert loaded.overrides == {"04_bg_pretrain": {"iterations": 10}}
    assert loaded.frame_ids == [0, 1, 2] and loaded.video_path is None
    assert loaded.frame_paths[2] == scene.absolute() / "frames" / "000002.png"
    assert (loaded.width, loaded.height) == (WIDTH, HEIGHT)
    cams = loaded.cameras
    assert cams is not None and cams.K.shape == (3, 3) and cams.dist is not None and cams.dist.shape == (4,)
    assert sorted(cams.poses) == [0, 1, 2]
    assert isinstance(cams.poses[1], CameraPose) and cams.poses[1].K is None and cams.poses[2].K[0, 0] == 25.0
    np.testing.assert_allclose(cams.poses[1].R, rotation_y(0.05))
    assert sorted(loaded.humans) == ["p0", "p1"] and loaded.has_3d_person_data()
    p0 = loaded.humans["p0"]
    assert p0.smpl is not None and p0.smpl.name == "smpl.npz" and sorted(p0.masks) == [0, 1, 2]
    assert [p.name for p in p0.references] == ["front.png"]
    cam1 = loaded.eval_cameras["cam1"]
    assert (cam1.width, cam1.height) == (EVAL_WIDTH, EVAL_HEIGHT) and sorted(cam1.poses) == [0]
    assert sorted(cam1.images) == sorted(cam1.union_masks) == [0, 1, 2]
    assert sorted(cam1.person_masks) == ["p0"] and sorted(cam1.person_masks["p0"]) == [0, 1, 2]
    kp2 = read_keypoints2d(p0.keypoints2d)
    assert kp2.layout == "coco17" and kp2.keypoints.shape == (3, 17, 3) and kp2.frame_ids.dtype == np.int64
    kp3 = read_keypoints3d(p0.keypoints3d)
    assert kp3.layout == "openpose25" and kp3.joints.shape == (3, 25, 4)


def test_a_checked_scene_reads_the_same_without_decoding_its_images(scene: Path) -> None:
    """What a pipeline stage loads (``checked``: headers only) equals what a full validation loads; a mask
    with a stray value is caught by the validation, which the stage's run has done before it."""
    assert repr(load_scene(scene, checked=True)) == repr(load_scene(scene))  # numpy arrays inside: by repr
    first_mask = sorted((scene / "humans" / "p0" / "masks").iterdir())[0]
    grey = np.array(Image.open(first_mask))
    grey[0, 0] = 7
    Image.fromarray(grey).save(first_mask)
    with pytest.raises(SceneError, match="only the values 0 and 255"):
        load_scene(scene)
    assert load_scene(scene, checked=True).frame_ids == [0, 1, 2]


def test_static_scene_without_optional_parts(scene: Path) -> None:
    remove("cameras.json", "eval", "humans")(scene)
    yaml_set(camera_motion="static")(scene)
    loaded = load_scene(scene)
    assert loaded.cameras is None and loaded.humans == {} and loaded.eval_cameras == {}
    assert not loaded.has_3d_person_data()


def test_video_scene_frame_ids(tmp_path: Path) -> None:
    root = build_valid_scene(tmp_path / "video_scene", n_frames=5, width=32, height=24)
    writer = cv2.VideoWriter(str(root / "video.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 10, (32, 24))
    assert writer.isOpened()
    for i in range(5):
        writer.write(rgb(32, 24, seed=i))
    writer.release()
    shutil.rmtree(root / "frames")
    loaded = load_scene(root)
    assert loaded.frame_ids == [0, 1, 2, 3, 4]
    assert loaded.frame_paths == {} and loaded.video_path == root.absolute() / "video.mp4"
    assert (loaded.width, loaded.height) == (32, 24)


# --- glimpse.io.images ---------------------------------------------------------------------------

def test_frame_names() -> None:
    assert frame_name(42) == "000042" and parse_frame_name("000042") == 42
    for stem in ("42", "0000042", "00004a", "٠٠٠٠٤٢", "000042 "):
        assert parse_frame_name(stem) is None
    with pytest.raises(ValueError):
        frame_name(1_000_000)


def test_image_helpers(tmp_path: Path) -> None:
    grey = np.arange(12 * 16, dtype=np.uint8).reshape(12, 16)
    write_png(tmp_path / "sub" / "grey.png", grey)
    colour = read_rgb(tmp_path / "sub" / "grey.png")
    assert colour.shape == (12, 16, 3) and colour.dtype == np.uint8 and (colour[..., 1] == grey).all()
    rgba = np.dstack([rgb(16, 12), np.zeros((12, 16), np.uint8)])
    write_png(tmp_path / "rgba.png", rgba)
    assert (read_rgb(tmp_path / "rgba.png") == rgba[..., :3]).all()
    m = mask(16, 12).astype(bool)
    write_png(tmp_path / "mask.png", m)
    assert (read_mask(tmp_path / "mask.png") == m).all()
    umask = os.umask(0o022)
    os.umask(umask)
    assert (tmp_path / "mask.png").stat().st_mode & 0o777 == 0o666 & ~umask  # as any new file, not 0600
    assert not list(tmp_path.glob(".*.tmp"))
    info = probe_image(tmp_path / "mask.png")
    assert (info.format, info.mode, info.width, info.height, info.bit_depth) == ("PNG", "L", 16, 12, 8)
    cv2.imwrite(str(tmp_path / "deep.png"), np.zeros((4, 5, 3), np.uint16))
    assert probe_image(tmp_path / "deep.png").bit_depth == 16
    Image.fromarray(rgb(16, 12)).save(tmp_path / "photo.jpg", quality=90)
    for name in ("mask.png", "deep.png", "rgba.png", "photo.jpg"):  # the header alone says the same
        assert read_image_header(tmp_path / name) == probe_image(tmp_path / name)
    (tmp_path / "bad.png").write_bytes(b"\x89PNG\r\n\x1a\n broken")
    with pytest.raises(ImageReadError):
        read_rgb(tmp_path / "bad.png")
    with pytest.raises(ImageReadError):
        read_image_header(tmp_path / "bad.png")
    with pytest.raises(ValueError):
        write_png(tmp_path / "f.png", np.zeros((4, 4), np.float32))


@pytest.mark.parametrize("held", [1, 3])
def test_a_held_out_frame_of_the_input_video_may_be_scored_only_between_the_scenes_frames(tmp_path, held):
    """Frames 0 and 2 are the input; frame 1 was held out of it for evaluation (as NeuMan's protocol holds
    frames of the video out): its held-out image and pose are valid. Frame 3 lies after the video."""
    from glimpse.scene.writer import SceneWriter
    from tests.scene_builder import _write_person, intrinsics

    ids = [0, 2]
    writer = SceneWriter(tmp_path / "scene", "gap", 10, "moving", "smpl")
    for i in ids:
        writer.frame(i, rgb(WIDTH, HEIGHT, seed=i))
    K = np.array(intrinsics(WIDTH, HEIGHT))
    writer.input_cameras(WIDTH, HEIGHT, K, None, {i: CameraPose(rotation_y(0.05 * i), np.array([0.0, 0.0, 3.0]))
                                                   for i in ids})
    _write_person(writer, "p0", ids, WIDTH, HEIGHT, seed=0)
    pose = CameraPose(rotation_y(0.05 * held), np.array([0.0, 0.0, 3.0]))
    writer.eval_camera("video", WIDTH, HEIGHT, K, pose.R, pose.t, poses={held: pose})
    union = mask(WIDTH, HEIGHT, seed=held) > 0
    writer.eval_view("video", held, rgb(WIDTH, HEIGHT, seed=10), union, {"p0": union})
    if held == 1:
        scene = load_scene(writer.finish())
        assert scene.frame_ids == [0, 2] and sorted(scene.eval_cameras["video"].images) == [1]
        assert np.allclose(scene.eval_cameras["video"].camera_at(1).R, pose.R)
    else:
        with pytest.raises(SceneError, match=r"eval image's frame id must be a frame of the scene, or lie between "
                                             r"its first and last frame"):
            writer.finish()
