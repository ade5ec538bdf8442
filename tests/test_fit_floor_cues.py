"""Two cues of the common floor (glimpse.fit.ground). The floor's tilt from where people's 2D torso axes meet
(torso_axis_planes, vertical_from_torsos): recovered from upright torsos projected by a camera looking down,
robust to bending ones, and left to the hint in the direction the axes do not tell. The people's common size
from a stature prior (stature_scale): a child beside an adult is taken for a child. And how a fitted floor is scored
(glimpse.fit.evaluate.floor_errors): its tilt split into the camera's pitch and roll."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from glimpse.cameras.model import PinholeCamera
from glimpse.fit.evaluate import floor_errors
from glimpse.fit.ground import stature_scale, torso_axis_planes, torso_axis_sigmas, vertical_from_torsos
from glimpse.fixtures.scenes import intrinsics, look_at_pose

CAMERA_CENTRE = np.array([0.4, 1.6, -2.5])
TRUE_UP = np.array([0.0, 1.0, 0.0])
HIP_M, SHOULDER_M, HALF_WIDTH_M = 0.9, 1.45, 0.17  # heights above the floor, half the hip and shoulder span
AXIS_SIGMA, HINT_SIGMA = np.radians(2.0), np.radians(5.0)  # pipeline.yaml's
ITERATIONS = 20


def _camera() -> PinholeCamera:
    R, t = look_at_pose(CAMERA_CENTRE, np.array([0.8, 0.5, 3.0]))  # looks down about 13 degrees
    return PinholeCamera(intrinsics(960, 720, 60.0), R, t, 960, 720)


def _torsos(camera: PinholeCamera, feet_xz: np.ndarray, lean: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """Hips and shoulders [T, 2, 2] in pixels of torsos standing at ``feet_xz`` [T, 2], leaning by ``lean`` [T, 3]
    (added to the up of the shoulders' midpoint, metres per metre)."""
    up = TRUE_UP + (0.0 if lean is None else lean)
    side = np.array([1.0, 0.0, 0.0]) * HALF_WIDTH_M
    feet = np.stack([feet_xz[:, 0], np.zeros(len(feet_xz)), feet_xz[:, 1]], 1)
    hips = feet + HIP_M * TRUE_UP
    shoulders = hips + (SHOULDER_M - HIP_M) * up
    pairs = [np.stack([camera.project(c + s)[0] for s in (side, -side)], 1) for c in (hips, shoulders)]
    return pairs[0], pairs[1]


def _planes(camera: PinholeCamera, hips: np.ndarray, shoulders: np.ndarray) -> np.ndarray:
    count = len(hips)
    return torso_axis_planes(hips, shoulders, np.repeat(camera.K[None], count, 0), np.repeat(camera.R[None], count, 0))


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0))))


def _tilted(axis: np.ndarray, deg: float) -> np.ndarray:
    """TRUE_UP turned by ``deg`` towards ``axis`` (unit, perpendicular to it)."""
    return np.cos(np.radians(deg)) * TRUE_UP + np.sin(np.radians(deg)) * axis


def test_each_axis_plane_holds_the_vertical_and_the_vanishing_point():
    """Independent of the fit: the line through a torso's two midpoints passes through the image of the
    vertical direction, K R up (the vertical vanishing point), and its plane's normal is perpendicular to up
    (to 1e-4: the midpoint of two projected points is not quite the projected midpoint)."""
    camera = _camera()
    rng = np.random.default_rng(0)
    hips, shoulders = _torsos(camera, rng.uniform([-2.0, 2.0], [3.0, 7.0], (12, 2)))
    planes = _planes(camera, hips, shoulders)
    assert np.abs(planes @ TRUE_UP).max() < 1e-4
    vanishing = camera.K @ camera.R @ TRUE_UP
    vanishing = vanishing[:2] / vanishing[2]
    low, high = hips.mean(1), shoulders.mean(1)
    direction, to_vanishing = high - low, vanishing - low
    cross = direction[:, 0] * to_vanishing[:, 1] - direction[:, 1] * to_vanishing[:, 0]
    sine = cross / np.linalg.norm(direction, axis=1) / np.linalg.norm(to_vanishing, axis=1)
    assert np.abs(sine).max() < 1e-4


def test_the_up_is_found_from_upright_torsos_across_the_view_and_bending_ones_weigh_little():
    camera = _camera()
    rng = np.random.default_rng(1)
    feet = rng.uniform([-2.0, 2.0], [3.0, 7.0], (80, 2))
    lean = np.zeros((80, 3))
    lean[:8] = [0.4, 0.0, 0.3]  # a tenth of the frames bend 25 degrees
    hips, shoulders = _torsos(camera, feet, lean)
    hips = hips + rng.normal(0.0, 1.0, hips.shape)  # pixels
    shoulders = shoulders + rng.normal(0.0, 1.0, shoulders.shape)
    forward = camera.R[2] - (camera.R[2] @ TRUE_UP) * TRUE_UP
    hint = _tilted(forward / np.linalg.norm(forward), 6.0)  # leaning towards the view, 6 degrees
    up = vertical_from_torsos(_planes(camera, hips, shoulders), np.ones(80), hint, np.full(80, AXIS_SIGMA),
                              HINT_SIGMA, ITERATIONS)
    assert _angle_deg(hint, TRUE_UP) > 5.9
    assert _angle_deg(up, TRUE_UP) < 0.5
    weights = np.ones(80)
    weights[:8] = 0.0  # the same without the bending frames: the robust fit had already set them aside
    clean = vertical_from_torsos(_planes(camera, hips, shoulders), weights, hint, np.full(80, AXIS_SIGMA),
                                 HINT_SIGMA, ITERATIONS)
    assert _angle_deg(up, clean) < 0.3


def test_a_short_torso_axis_is_trusted_less():
    """The axis's own lean and its ends' pixel noise over its length, in quadrature: 10 px of torso with 1 px of
    noise is off by up to 0.1 rad, 150 px by the lean alone."""
    hips = np.array([[[0.0, 100.0], [4.0, 100.0]], [[0.0, 300.0], [40.0, 300.0]]])
    shoulders = hips - np.array([[[0.0, 10.0]], [[0.0, 150.0]]])
    sigmas = torso_axis_sigmas(hips, shoulders, AXIS_SIGMA, 1.0)
    assert np.allclose(sigmas, np.hypot(AXIS_SIGMA, [0.1, 1.0 / 150.0]))


def test_torsos_in_one_image_column_leave_the_pitch_to_the_hint():
    """Torsos straight ahead of the camera all lie in its vertical plane of symmetry: they tell the roll,
    not the pitch, which stays the hint's."""
    R, t = look_at_pose(np.array([0.0, 1.6, -2.5]), np.array([0.0, 0.5, 3.0]))
    camera = PinholeCamera(intrinsics(960, 720, 60.0), R, t, 960, 720)
    feet = np.stack([np.zeros(30), np.linspace(2.0, 7.0, 30)], 1)
    hips, shoulders = _torsos(camera, feet)
    forward = camera.R[2] - (camera.R[2] @ TRUE_UP) * TRUE_UP
    forward /= np.linalg.norm(forward)
    hint = _tilted(forward, 4.0)
    up = vertical_from_torsos(_planes(camera, hips, shoulders), np.ones(30), hint, np.full(30, AXIS_SIGMA),
                              HINT_SIGMA, ITERATIONS)
    assert abs(_angle_deg(up, hint)) < 0.05
    rolled = _tilted(camera.R[0], 4.0)  # a hint rolled sideways is corrected, but for its share: 1 in 1 + 30 frames
    up = vertical_from_torsos(_planes(camera, hips, shoulders), np.ones(30), rolled, np.full(30, AXIS_SIGMA),
                              HINT_SIGMA, ITERATIONS)
    assert _angle_deg(up, TRUE_UP) < 0.2


STATURE_PRIOR = dict(adult_m=1.76, adult_sigma=0.05, child_m=1.25, child_sigma=0.2, child_share=0.25,
                     search=0.7, step=0.001)  # pipeline.yaml's, the free body's template stature


@pytest.mark.parametrize("true_statures", [(1.88, 1.39), (1.84, 1.42), (1.70, 1.83)])
def test_the_common_size_takes_the_taller_of_an_adult_and_a_child_for_the_adult(true_statures):
    """Statures known up to one factor (the floor measures them relative to each other): scaled 15% too large, the
    prior gives an adult and a child back as an adult near 1.76 m and a child, two adults with their geometric
    mean at 1.76 m: a mean over both (1.76 m on average) would make the child 1.5 m and the adult 2.0."""
    statures = np.array(true_statures) * 1.15
    scaled = statures * stature_scale(statures, **STATURE_PRIOR)
    if min(true_statures) < 1.5:
        assert abs(scaled.max() - 1.76) < 0.03
        assert np.isclose(scaled.min() / scaled.max(), min(true_statures) / max(true_statures))
    else:
        assert abs(np.sqrt(scaled.prod()) - 1.76) < 0.01
    assert np.isclose(stature_scale(np.array([np.nan, np.nan]), **STATURE_PRIOR), 1.0)


def test_a_fitted_floors_errors_split_into_the_cameras_pitch_and_roll():
    """glimpse.fit.evaluate.floor_errors against an up turned by known angles about the camera's own x axis (the
    view tipping towards or away from the camera: pitch) and then about its viewing axis (roll)."""
    camera = _camera()
    for pitch_deg, roll_deg in ((3.0, 0.0), (0.0, -2.0), (1.5, 4.0)):
        in_camera = Rotation.from_euler("x", -pitch_deg, degrees=True)  # +pitch: the up leans towards the view
        in_camera = Rotation.from_euler("z", roll_deg, degrees=True) * in_camera  # +roll: towards image right
        turn = camera.R.T @ in_camera.as_matrix() @ camera.R  # the same turn in world axes
        fitted = turn @ TRUE_UP
        errors = floor_errors(fitted, 1.5, CAMERA_CENTRE, camera.R, TRUE_UP)
        assert errors["tilt_deg"] == pytest.approx(_angle_deg(fitted, TRUE_UP), abs=1e-9)
        assert errors["pitch_error_deg"] == pytest.approx(pitch_deg, abs=0.1)
        assert errors["roll_error_deg"] == pytest.approx(roll_deg, abs=0.1)
        assert errors["camera_height_error_m"] == pytest.approx(1.5 - CAMERA_CENTRE[1])
