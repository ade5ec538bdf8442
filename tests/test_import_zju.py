"""ZJU-MoCap import on a miniature copy of the dataset's layout (annots.npy with millimetre translations and
distorted cameras, Camera_B<k>/ images, mask/ and mask_cihp/ with 0/1 values, EasyMocap's new_params/ with Rh and
Th): the imported scene's cameras, bodies and masks must agree with the source to numerical precision, checked
with smplx and OpenCV, not with the importer's own code."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from PIL import Image
from scipy.spatial.transform import Rotation

from glimpse.cli import main as cli
from glimpse.errors import EXIT_BAD_INPUT, GlimpseError
from glimpse.importers import import_dataset
from glimpse.importers.common import ImportOptions, parse_span
from glimpse.scene import load_scene
from tests.body_files import write_random_smpl_pkl

WIDTH, HEIGHT, FRAMES, CAMERAS = 80, 64, 5, 3


def look_at(centre: np.ndarray, target: np.ndarray, down: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera (R, t) of an OpenCV camera at ``centre`` looking at ``target``, image down ~ ``down``."""
    z = (target - centre) / np.linalg.norm(target - centre)
    x = np.cross(down, z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    return R, -R @ centre


def write_source(root: Path, rng: np.random.Generator) -> dict:
    """CoreView_377/ in miniature; returns the ground truth it was made from."""
    folder = root / "CoreView_377"
    K = np.array([[70.0, 0, 41.3], [0, 72.0, 30.8], [0, 0, 1]])
    truth = {"K": [], "D": [], "R": [], "t": []}
    for c in range(CAMERAS):
        angle = 2 * np.pi * c / CAMERAS
        centre = np.array([3.0 * np.cos(angle), 3.0 * np.sin(angle), -1.2])  # ZJU's world: z down
        R, t = look_at(centre, np.array([0.0, 0.0, -0.9]), np.array([0.0, 0.0, 1.0]))
        truth["K"].append(K + np.diag([c, c, 0]))
        truth["D"].append(np.array([-0.2 + 0.05 * c, 0.05, 0.001, -0.002, 0.01]))
        truth["R"].append(R)
        truth["t"].append(t)
    ims = []
    for f in range(FRAMES):
        paths = []
        for c in range(CAMERAS):
            rel = f"Camera_B{c + 1}/{f:06d}.jpg"
            (folder / rel).parent.mkdir(parents=True, exist_ok=True)
            Image.fromarray(rng.integers(0, 255, (HEIGHT, WIDTH, 3), dtype=np.uint8)).save(folder / rel, quality=95)
            mask = np.zeros((HEIGHT, WIDTH), np.uint8)
            mask[10 + f: 50, 20 + c: 45] = 1  # 0/1 values, as the dataset's masks may be
            other = np.zeros_like(mask)
            other[40:55, 30:60] = 1
            for name, values in (("mask", mask), ("mask_cihp", other)):
                path = folder / name / f"Camera_B{c + 1}" / f"{f:06d}.png"
                path.parent.mkdir(parents=True, exist_ok=True)
                Image.fromarray(values).save(path)
            paths.append(rel)
        ims.append({"ims": np.array(paths)})
    cams = {"K": truth["K"], "D": [d.reshape(5, 1) for d in truth["D"]], "R": truth["R"],
            "T": [t.reshape(3, 1) * 1000.0 for t in truth["t"]]}
    np.save(folder / "annots.npy", {"cams": cams, "ims": ims}, allow_pickle=True)
    shapes = rng.normal(0, 0.5, 10)
    truth["poses"], truth["Rh"], truth["Th"] = [], [], []
    (folder / "new_params").mkdir()
    for f in range(FRAMES):
        poses = np.concatenate([np.zeros(3), rng.normal(0, 0.2, 69)])
        Rh, Th = rng.normal(0, 0.6, 3), np.array([0.1 * f, -0.05, -0.9]) + rng.normal(0, 0.02, 3)
        np.save(folder / "new_params" / f"{f}.npy", {"poses": poses[None], "Rh": Rh[None], "Th": Th[None],
                                                      "shapes": shapes[None]}, allow_pickle=True)
        truth["poses"].append(poses)
        truth["Rh"].append(Rh)
        truth["Th"].append(Th)
    truth["shapes"] = shapes
    return truth


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    root = tmp_path_factory.mktemp("zju")
    truth = write_source(root / "source", np.random.default_rng(0))
    model = write_random_smpl_pkl(root / "SMPL_NEUTRAL.pkl", seed=3, chumpy_style=False)
    scene = import_dataset("zju-mocap", root / "source", root / "scene",
                           ImportOptions(sequence="377", cameras=("0", "2"), frames=parse_span("1:5"), eval_every=2,
                                         body_models={"neutral": model}))
    return truth, model, root / "source" / "CoreView_377", load_scene(scene)


def smplx_vertices(model_path, betas, global_orient, body_pose, transl) -> np.ndarray:
    smplx = pytest.importorskip("smplx")
    layer = smplx.SMPL(model_path=str(model_path), dtype=torch.float64, batch_size=len(global_orient))
    as_tensor = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float64)  # noqa: E731
    out = layer(betas=as_tensor(np.tile(betas, (len(global_orient), 1))), global_orient=as_tensor(global_orient),
                body_pose=as_tensor(body_pose), transl=as_tensor(transl))
    return out.vertices.detach().numpy()


def test_bodies_are_easymocaps_rh_th_bodies_in_smplx_convention(imported):
    truth, model, _, scene = imported
    body = dict(np.load(scene.humans["p0"].smpl))
    assert body["frame_ids"].tolist() == [1, 2, 3, 4]
    rows = slice(1, 5)
    poses, Rh, Th = (np.stack(truth[k])[rows] for k in ("poses", "Rh", "Th"))
    # EasyMocap: V = R(Rh) SMPL(poses, shapes) + Th, the body turned about the model's origin
    unplaced = smplx_vertices(model, truth["shapes"], np.zeros((4, 3)), poses[:, 3:], np.zeros((4, 3)))
    source = np.einsum("tij,tvj->tvi", Rotation.from_rotvec(Rh).as_matrix(), unplaced) + Th[:, None]
    ours = smplx_vertices(model, body["betas"], body["global_orient"], body["body_pose"], body["transl"])
    assert np.abs(ours - source).max() < 1e-7  # metres; smplx adds 1e-8 to every axis-angle it turns


def test_cameras_and_masks_agree_with_the_source(imported):
    truth, model, folder, scene = imported
    assert (scene.width, scene.height) == (WIDTH, HEIGHT) and scene.camera_motion == "static"
    points = np.array([[0.1, 0.2, -0.9], [-0.3, 0.1, -0.5], [0.2, -0.2, -1.4]])
    for fid in (1, 4):  # the input camera (Camera_B1, distorted as the source)
        pose = scene.cameras.poses[fid]
        ours, _ = cv2.projectPoints(points, cv2.Rodrigues(pose.R)[0], pose.t, scene.cameras.K, scene.cameras.dist)
        theirs, _ = cv2.projectPoints(points, cv2.Rodrigues(truth["R"][0])[0], truth["t"][0], truth["K"][0],
                                      truth["D"][0])
        assert np.abs(ours - theirs).max() < 1e-9
    held = scene.eval_cameras["Camera_B3"]  # pinhole, on undistorted images
    pixels, _ = cv2.projectPoints(points, cv2.Rodrigues(held.R)[0], held.t, held.K, None)
    distorted, _ = cv2.projectPoints(points, cv2.Rodrigues(truth["R"][2])[0], truth["t"][2], truth["K"][2],
                                     truth["D"][2])
    undistorted = cv2.undistortPoints(distorted, truth["K"][2], truth["D"][2], P=truth["K"][2])
    assert np.abs(pixels - undistorted).max() < 1e-6
    assert sorted(held.images) == [1, 3] and set(scene.eval_cameras) == {"Camera_B3"}  # every 2nd imported frame
    from glimpse.io.images import read_mask

    source = (np.asarray(Image.open(folder / "mask" / "Camera_B1" / "000002.png")) != 0) | (
        np.asarray(Image.open(folder / "mask_cihp" / "Camera_B1" / "000002.png")) != 0)
    assert np.array_equal(read_mask(scene.humans["p0"].masks[2]), source)
    assert "model_path" in str(scene.overrides["body"]) and scene.body_model == "smpl"


class RunsCode:
    def __reduce__(self):
        return (print, ("this must not run",))


def test_pickled_npy_files_are_read_without_running_code(tmp_path):
    from glimpse.io.numpy_pickle import load_object_npy

    np.save(tmp_path / "evil.npy", np.array({"cams": RunsCode()}, dtype=object), allow_pickle=True)
    with pytest.raises(GlimpseError, match="refusing to unpickle builtins.print"):
        load_object_npy(tmp_path / "evil.npy")
    np.save(tmp_path / "plain.npy", np.arange(6.0).reshape(2, 3))
    assert load_object_npy(tmp_path / "plain.npy").tolist() == [[0, 1, 2], [3, 4, 5]]
    doc = {"K": [np.eye(3)], "ims": [{"ims": np.array(["a.jpg"])}]}
    np.save(tmp_path / "dict.npy", doc, allow_pickle=True)
    loaded = load_object_npy(tmp_path / "dict.npy")
    assert np.array_equal(loaded["K"][0], np.eye(3)) and loaded["ims"][0]["ims"].tolist() == ["a.jpg"]


def test_bad_sources_get_one_message(tmp_path, imported, capsys):
    with pytest.raises(GlimpseError, match="--body-model"):
        import_dataset("zju-mocap", imported[2], tmp_path / "s", ImportOptions())
    with pytest.raises(GlimpseError, match="no annots.npy"):
        import_dataset("zju-mocap", tmp_path, tmp_path / "s", ImportOptions(body_models={"neutral": imported[1]}))
    with pytest.raises(GlimpseError, match="not a camera of this sequence"):
        import_dataset("zju-mocap", imported[2], tmp_path / "s", ImportOptions(cameras=("7",),
                                                                                body_models={"neutral": imported[1]}))
    assert cli(["import", "hi5d", str(tmp_path), str(tmp_path / "s")]) == EXIT_BAD_INPUT
    assert "Glimpse imports emdb, hi4d, neuman, panoptic, zju-mocap" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


def test_the_held_out_spacing_comes_from_pipeline_yaml_and_the_command_line(imported, tmp_path, monkeypatch):
    from glimpse.config import load_pipeline_yaml

    assert ImportOptions().eval_every == load_pipeline_yaml()["import"]["eval_every"]  # one default, kept equal
    seen = []
    monkeypatch.setattr("glimpse.importers.import_dataset", lambda dataset, source, scene, options: seen.append(
        options.eval_every) or scene)
    for extra, expected in (([], load_pipeline_yaml()["import"]["eval_every"]), (["--eval-every", "3"], 3)):
        assert cli(["import", "zju-mocap", str(imported[2]), str(tmp_path / "s"), *extra]) == 0
        assert seen[-1] == expected
    assert cli(["import", "zju-mocap", str(imported[2]), str(tmp_path / "s"), "--eval-every", "0"]) == EXIT_BAD_INPUT
