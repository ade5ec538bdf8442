"""Stage 02 (provided mode so far): body parameters for the pipeline's frames, keypoint residuals."""

import numpy as np
import pytest

from glimpse.body.params import read_body_params
from glimpse.errors import GlimpseError, NotImplementedStageError
from glimpse.fixtures.scenes import KEYPOINT_NOISE_2D_PX_AT_320, KEYPOINT_NOISE_3D_M, make_scene
from tests.stage_helpers import read_json, run


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    root = tmp_path_factory.mktemp("fit")
    scene = make_scene("demo", root / "demo", "tiny", seed=1)
    run("01_sfm", scene, root / "out")
    return scene, root / "out", run("02_smpl_fit", scene, root / "out")


def test_provided_parameters_are_kept_for_the_frames_with_a_camera(demo):
    scene, _, out = demo
    for pid in ("p0", "p1"):
        params = read_body_params(out / "humans" / pid / "body.npz")
        given = np.load(scene / "humans" / pid / "smpl.npz")
        assert np.array_equal(params.frame_ids, given["frame_ids"]) and params.scale == 1.0
        assert np.allclose(params.body_pose, given["body_pose"]) and params.body_model == "free"
        assert not params.interpolated.any()


def test_residuals_match_the_keypoint_noise(demo):
    """The fixture's keypoints are the body's own plus Gaussian noise: a mean residual of sigma*sqrt(8/pi)
    in 3D and sigma*sqrt(pi/2) in 2D (visible, undropped keypoints)."""
    _, _, out = demo
    report = read_json(out / "humans" / "p0" / "fit_report.json")
    assert report["mode"] == "provided" and len(report["per_frame"]) == 6
    expected_3d = KEYPOINT_NOISE_3D_M * np.sqrt(8 / np.pi)
    expected_2d = KEYPOINT_NOISE_2D_PX_AT_320 * 64 / 320 * np.sqrt(np.pi / 2)
    assert report["keypoints3d_residual"]["mean"] == pytest.approx(expected_3d, rel=0.35)
    assert report["keypoints2d_residual"]["mean"] == pytest.approx(expected_2d, rel=0.5)


def test_fitting_modes_stop_clearly_until_they_land(demo, tmp_path):
    scene, out, _ = demo
    with pytest.raises(NotImplementedStageError, match=r"person p0: stage 02 mode keypoints3d is not implemented yet"):
        run("02_smpl_fit", scene, out, "02_smpl_fit.mode=keypoints3d")
    bare = make_scene("sparse", tmp_path / "sparse", "tiny", seed=0)
    (bare / "humans" / "p0" / "smpl.npz").unlink()
    (bare / "humans" / "p0" / "keypoints3d.npz").unlink()
    with pytest.raises(GlimpseError, match=r"02_smpl_fit.mode=provided needs humans/p0/smpl.npz"):
        run("01_sfm", bare, tmp_path / "out")
        run("02_smpl_fit", bare, tmp_path / "out", "02_smpl_fit.mode=provided")


def test_body_params_files_carry_their_version(tmp_path):
    np.savez(tmp_path / "body.npz", format=np.array("glimpse-body-params/9"))
    with pytest.raises(GlimpseError, match="this reader knows glimpse-body-params/1"):
        read_body_params(tmp_path / "body.npz")
