"""One floor for everyone: where a static camera's people stand tells each one's size.

A single view cannot tell a person's size from its distance: a body scaled by s about the
camera centre projects to exactly the same pixels. Fitted one at a time, a child is pulled
towards the shape prior's adult height and placed too far, a tall adult too near. But people
stand on one floor. Each fitted person's foot contacts (sole points that stay put in the image
and are the body's lowest) lie on a plane parallel to the true floor at ``s_i`` times its
distance from the camera; the pooled contacts give the floor's normal and, person by person,
the factor that brings everyone onto one plane. People placed metrically (3D keypoints,
given bodies) fix the camera's height above that floor; without them the factors' geometric
mean is kept at 1 (the fitted heights on average), or a stature prior picks the most probable
common size (``stature_scale``). Where the contacts do not tell the floor's tilt, the people's
2D torso axes do: they meet at the vertical vanishing point (``vertical_from_torsos``).

Pure functions on arrays (world units; the floor's normal points up, towards the camera).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SOLE_LANDMARKS = ("left_heel", "left_big_toe", "right_heel", "right_big_toe")  # the sole points a foot stands on
SPAN_TOLERANCE_S = 1e-9  # frame times are frame ids / fps: 3 / 30 s apart counts as at least 0.1 s


def height_above_plane(points, normal, camera_centre, camera_height: float):
    """[..., 3] world points -> [...] signed height above the plane ``normal . (x - camera_centre) =
    -camera_height`` (numpy arrays or torch tensors alike; world units)."""
    return (points - camera_centre) @ normal + camera_height


@dataclass(frozen=True)
class Floor:
    """The plane ``normal . (x - camera_centre) = -camera_height``: normal [3] unit (up), camera_centre [3]
    and camera_height (the camera centre's height above the floor) in world units."""

    normal: np.ndarray
    camera_centre: np.ndarray
    camera_height: float

    def height_of(self, points: np.ndarray) -> np.ndarray:
        """[..., 3] world points -> [...] signed height above the floor (world units)."""
        return height_above_plane(points, self.normal, self.camera_centre, self.camera_height)


def speed_across_view(points: np.ndarray, times_s: np.ndarray, frame_ids: np.ndarray, camera_centre: np.ndarray,
                      max_gap_frames: int, span_s: float = 0.0) -> np.ndarray:
    """[T, S] speed of points [T, S, 3] across the camera's view (the component along the viewing ray
    dropped: a 2D fit's depth jitters, its image position does not), between the nearest frames at least
    ``span_s`` seconds before and after (the farthest reachable where the track is shorter; one-sided at the
    ends; inf where a frame has no neighbour). Frames more than ``max_gap_frames`` apart are not bridged.
    With ``span_s`` 0 the neighbours are the adjacent frames; a span keeps the frame-to-frame jitter of a fast
    video (33 fps) from reading as speed (jitter over a difference shrinks as the time between its frames
    grows). ``camera_centre``: [3], or [T, 3] for a moving camera (each frame's centre)."""
    frames = len(points)
    camera_centre = np.broadcast_to(camera_centre, (frames, 3))
    speed = np.full(points.shape[:2], np.inf)
    for t in range(frames):
        before = _neighbour_at(times_s, frame_ids, t, -1, max_gap_frames, span_s)
        after = _neighbour_at(times_s, frame_ids, t, 1, max_gap_frames, span_s)
        if before == after:
            continue
        velocity = (points[after] - points[before]) / (times_s[after] - times_s[before])
        ray = points[t] - camera_centre[t]
        ray = ray / np.linalg.norm(ray, axis=-1, keepdims=True).clip(min=1e-12)
        across = velocity - (velocity * ray).sum(-1, keepdims=True) * ray
        speed[t] = np.linalg.norm(across, axis=-1)
    return speed


def _neighbour_at(times_s: np.ndarray, frame_ids: np.ndarray, t: int, step: int, max_gap_frames: int,
                  span_s: float) -> int:
    """Index of the nearest frame ``step`` (-1 or 1) ways from t that is at least ``span_s`` away in time,
    walking over frames at most ``max_gap_frames`` apart; the farthest reached when none is, t when none is."""
    k = t
    while 0 <= k + step < len(times_s) and abs(int(frame_ids[k + step]) - int(frame_ids[k])) <= max_gap_frames:
        k += step
        if span_s <= 0 or abs(times_s[k] - times_s[t]) >= span_s - SPAN_TOLERANCE_S:
            break
    return k


def foot_contacts(soles: np.ndarray, up: np.ndarray, speed_m_s: np.ndarray, body_scale: float,
                  max_speed_m_s: float, max_height_m: float) -> np.ndarray:
    """[T, S] bool: sole points [T, S, 3] that touch the ground, judged on the body alone: slower than
    ``max_speed_m_s`` (speed_m_s [T, S] in world units per second; metres = world units / body_scale)
    and within ``max_height_m`` of the frame's lowest sole point along the body's up [T, 3]."""
    height = (soles * up[:, None]).sum(-1) / body_scale
    low = height - height.min(1, keepdims=True) <= max_height_m
    return low & (speed_m_s / body_scale <= max_speed_m_s)


def standing_weights(up: np.ndarray, hips: np.ndarray, knees: np.ndarray, sigma_deg: float) -> np.ndarray:
    """[T] weights of frames for telling which way is up from the body's own up [T, 3]: exp(-(a / sigma)^2),
    a the angle between -up and the thighs (hips [T, 2, 3] to knees [T, 2, 3], averaged). A standing or
    walking body's pelvis is upright; a crouching or sitting one's is often fitted tilted."""
    thigh = (knees - hips).mean(1)
    thigh = thigh / np.linalg.norm(thigh, axis=-1, keepdims=True).clip(min=1e-12)
    angle = np.degrees(np.arccos(np.clip(-(thigh * up).sum(-1), -1.0, 1.0)))
    return np.exp(-((angle / sigma_deg) ** 2))


def lowest_points(soles: np.ndarray, up: np.ndarray) -> np.ndarray:
    """[T, 3] each frame's lowest sole point along ``up`` [3] (soles [T, S, 3]): a standing, walking or
    dancing person has a foot on the floor in nearly every frame, so these sample the floor far more
    often than the contacts do."""
    return soles[np.arange(len(soles)), (soles @ up).argmin(1)]


def floor_normal(contacts: list[np.ndarray], up_hint: np.ndarray, prior_m: float) -> np.ndarray:
    """The unit normal shared by the people's contact planes.

    contacts: per person [N_i, 3] points on the ground (world). Each person's contacts lie on its own
    plane (its placement is off by its own factor) with the common normal, so the normal is the
    direction of least spread of the contacts, each person's centred on its own mean. Where the
    contacts spread less than ``prior_m`` (one person walking a straight line leaves the tilt
    about that line open) the people's mean up ``up_hint`` decides."""
    up = up_hint / np.linalg.norm(up_hint)
    scatter = prior_m**2 * (np.eye(3) - np.outer(up, up))
    count = sum(len(c) for c in contacts)
    for points in contacts:
        if len(points):
            centred = points - points.mean(0)
            scatter += centred.T @ centred / max(count, 1)
    _, vectors = np.linalg.eigh(scatter)
    normal = vectors[:, 0]
    return normal if normal @ up >= 0 else -normal


def person_camera_heights(contacts: list[np.ndarray], normal: np.ndarray, camera_centre: np.ndarray) -> np.ndarray:
    """[P] the camera centre's height above each person's ground plane (median over its points on the
    ground; nan for a person without any)."""
    return np.array([np.median((camera_centre - points) @ normal) if len(points) else np.nan for points in contacts])


def near_own_plane(points: list[np.ndarray], normal: np.ndarray, camera_centre: np.ndarray,
                   tolerance: float) -> list[np.ndarray]:
    """Each person's points [N_i, 3] less those more than ``tolerance`` (world units) off the person's
    own plane along ``normal`` (median height): a lifted foot, a jump, a bad frame."""
    heights = person_camera_heights(points, normal, camera_centre)
    return [p[np.abs((camera_centre - p) @ normal - h) <= tolerance] if np.isfinite(h) else p
            for p, h in zip(points, heights)]


def plane_weights(points: list[np.ndarray], normal: np.ndarray, camera_centre: np.ndarray,
                  noise: float) -> np.ndarray:
    """[P] how much each person's ground plane is trusted: its number of points over the squared spread
    of their heights about their median (robust: 1.4826 times the median absolute deviation) plus
    ``noise``^2 (world units). A person whose legs were fitted wrong has feet all over the place."""
    weights = []
    for p in points:
        if not len(p):
            weights.append(0.0)
            continue
        heights = (camera_centre - p) @ normal
        spread = 1.4826 * np.median(np.abs(heights - np.median(heights)))
        weights.append(len(p) / (spread**2 + noise**2))
    return np.array(weights)


def placement_factors(heights: np.ndarray, anchored: np.ndarray, weights: np.ndarray | None = None,
                      measured: np.ndarray | None = None, measured_weights: np.ndarray | None = None
                      ) -> tuple[float, np.ndarray]:
    """(camera height, [P] factors): person i moved to ``factor_i`` times its distance from the camera
    (and scaled by it) stands on one floor with everyone. The camera height is the median of the
    anchored people's (placed metrically); else the weighted median of ``measured`` [P] (the camera's height
    above the floor as a metric cue measured it through person i, nan where none; weights ``measured_weights``
    [P]: one person whose cue is off, a child's turning steps taken for planted feet, does not move it); else
    the geometric mean of all, weighted by ``weights`` [P] (equal when None).
    Factor 1 for anchored people and for people without ground points (nan heights)."""
    known = np.isfinite(heights) & (heights > 0)
    if not known.any():
        return float("nan"), np.ones(len(heights))
    cued = np.zeros(len(heights), bool) if measured is None else known & np.isfinite(measured) & (measured > 0)
    if (known & anchored).any():
        camera_height = float(np.median(heights[known & anchored]))
    elif cued.any():
        camera_height = _weighted_median(measured[cued], np.ones(cued.sum()) if measured_weights is None
                                         else np.asarray(measured_weights, float)[cued])
    else:
        w = np.ones(len(heights)) if weights is None else np.asarray(weights, float)
        w = np.where(known, w, 0.0)
        if w.sum() <= 0:
            w = known.astype(float)
        camera_height = float(np.exp((w * np.log(np.where(known, heights, 1.0))).sum() / w.sum()))
    factors = np.where(known & ~anchored, camera_height / np.where(known, heights, 1.0), 1.0)
    return camera_height, factors


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """The first of the sorted ``values`` [N] at which the cumulative ``weights`` [N] reach half their total; the
    mean of it and the next where they reach exactly half (equal weights: the usual median)."""
    order = np.argsort(values)
    cumulative = np.cumsum(weights[order])
    half = 0.5 * cumulative[-1]
    k = int(np.searchsorted(cumulative, half))
    if k + 1 < len(values) and np.isclose(cumulative[k], half, rtol=1e-12, atol=0.0):
        return float(0.5 * (values[order][k] + values[order][k + 1]))
    return float(values[order][k])


def implausible_factors(factors: np.ndarray, max_factor: float) -> list[int]:
    """Indices of the placement ``factors`` [P] beyond ``max_factor`` either way (above it or below its inverse):
    a person moved to that many times its distance would be that many times its fitted size, which no
    person's size error explains (a fit with its legs wrong does)."""
    return [i for i, factor in enumerate(factors) if not 1.0 / max_factor <= factor <= max_factor]


def parallax_factor(soles: np.ndarray, contact: np.ndarray, centres: np.ndarray, frame_ids: np.ndarray,
                    max_gap_frames: int) -> tuple[float, float]:
    """(factor, relative standard error) that makes a moving camera's person's planted feet stand still.

    soles [T, S, 3] the fitted sole points (world), contact [T, S] bool, centres [T, 3] each frame's camera
    centre, frame_ids [T] (consecutive frames one apart). A 2D fit placed wrong is, frame by frame, its true
    self scaled about that frame's camera centre: a foot that stands still at x is fitted at
    ``c_t + (x - c_t) / s``, so within a run of contact frames (one sole point, frames at most
    ``max_gap_frames`` apart) its offset from the camera moves by ``-1 / s`` times the camera's own move.
    That slope is fitted by least squares with the camera's move as the regressor (exact, where the fitted
    points are noisy: the other way round the noise would shrink the factor); the camera's travel during
    the runs is what measures it: (nan, inf) without runs of at least two frames, or when the camera does
    not move during them.

    The error is the larger of the least squares' own and the spread of the runs' separate slopes about
    theirs (each run weighted by its camera travel): a fit's feet slide differently in every run, which the
    residuals of one run do not show."""
    runs = []  # per run: (camera offsets [n, 3], sole offsets from the camera [n, 3]), each about the run's mean
    for point in range(soles.shape[1]):
        rows = np.nonzero(contact[:, point])[0]
        if not len(rows):
            continue
        breaks = np.nonzero(np.diff(frame_ids[rows]) > max_gap_frames)[0] + 1
        for run in np.split(rows, breaks):
            if len(run) >= 2:
                offset = soles[run, point] - centres[run]
                runs.append((centres[run] - centres[run].mean(0), offset - offset.mean(0)))
    travel = np.array([float((camera**2).sum()) for camera, _ in runs])  # each run's weight
    if not runs or travel.sum() <= 0:
        return float("nan"), float("inf")
    cross = np.array([float((camera * offset).sum()) for camera, offset in runs])
    slope = cross.sum() / travel.sum()  # -1 / factor
    if slope >= 0:
        return float("nan"), float("inf")
    squared = sum(float(((offset - slope * camera) ** 2).sum()) for camera, offset in runs)
    dof = max(3 * sum(len(camera) - 1 for camera, _ in runs) - 1, 1)
    error = np.sqrt(squared / dof / travel.sum())
    moved = travel > 0
    if moved.sum() >= 2:  # the runs' own slopes, spread about the pooled one
        spread = travel[moved] * (cross[moved] / travel[moved] - slope)
        error = max(error, np.sqrt((spread**2).sum() * moved.sum() / (moved.sum() - 1)) / travel.sum())
    return float(-1.0 / slope), float(error / -slope)  # the factor's relative error is the slope's


def torso_axis_planes(hips_px: np.ndarray, shoulders_px: np.ndarray, K: np.ndarray, R: np.ndarray) -> np.ndarray:
    """[T, 3] unit world normals of the planes through the camera centre and each frame's 2D torso axis
    (hip midpoint to shoulder midpoint). hips_px, shoulders_px [T, 2, 2] pixels (left, right); K, R [T, 3, 3]
    intrinsics and world-to-camera rotations. An upright torso lies in its plane, so the vertical does too:
    the vertical vanishing point, which a camera looking down puts below the image, is where the axes meet."""
    ones = np.ones((len(hips_px), 1))
    inv_K = np.linalg.inv(K)
    low = np.einsum("tij,tj->ti", inv_K, np.concatenate([hips_px.mean(1), ones], 1))
    high = np.einsum("tij,tj->ti", inv_K, np.concatenate([shoulders_px.mean(1), ones], 1))
    normals = np.einsum("tji,tj->ti", R, np.cross(low, high))  # camera -> world: R^T
    return normals / np.linalg.norm(normals, axis=1, keepdims=True).clip(min=1e-12)


def vertical_from_torsos(planes: np.ndarray, weights: np.ndarray, up_hint: np.ndarray, sigmas_rad: np.ndarray,
                         hint_sigma_rad: float, iterations: int) -> np.ndarray:
    """The world's up from torso axis planes [N, 3] (torso_axis_planes) with weights [N] in [0, 1]: the unit n
    minimising sum w rho((m . n) / sigma)  +  |n - (n . u) u|^2 / hint_sigma^2, rho Cauchy (a leaning or
    bending torso is an outlier), sigma [N] each axis's uncertainty (radians), u = ``up_hint``. Directions the
    planes do not tell (people all in one image column leave the camera's pitch open) stay with the hint."""
    up = up_hint / np.linalg.norm(up_hint)
    prior = (np.eye(3) - np.outer(up, up)) / hint_sigma_rad**2
    normal = up
    for _ in range(iterations):
        robust = 1.0 / (1.0 + ((planes @ normal) / sigmas_rad) ** 2)
        scatter = prior + (planes * (weights * robust / sigmas_rad**2)[:, None]).T @ planes
        _, vectors = np.linalg.eigh(scatter)
        normal = vectors[:, 0] if vectors[:, 0] @ up >= 0 else -vectors[:, 0]
    return normal


def torso_axis_sigmas(hips_px: np.ndarray, shoulders_px: np.ndarray, axis_sigma_rad: float,
                      keypoint_noise_px: float) -> np.ndarray:
    """[T] how far each frame's 2D torso axis (hips [T, 2, 2] to shoulders [T, 2, 2], pixels) may be off the
    vertical, radians: ``axis_sigma_rad`` (the body's own lean) and the keypoints' noise over the axis's length
    (each end a midpoint of two keypoints), in quadrature. A torso 10 px long in a small frame tells little."""
    length = np.linalg.norm(shoulders_px.mean(1) - hips_px.mean(1), axis=-1).clip(min=1e-6)
    return np.hypot(axis_sigma_rad, keypoint_noise_px / length)


def stature_scale(statures_m: np.ndarray, adult_m: float, adult_sigma: float, child_m: float, child_sigma: float,
                  child_share: float, search: float, step: float) -> float:
    """The one factor c that makes the people's statures [P] (metres, nan where unknown) most probable under a
    prior of two log-normal modes: adults around ``adult_m`` (relative spread ``adult_sigma``) and, with prior
    probability ``child_share``, children around ``child_m`` (``child_sigma``). On one floor the people's statures
    relative to one another are measured (their feet and heads in the image); only their common size is not: a
    child beside an adult is then taken for a child rather than both for two mid-sized people. c is searched
    in log steps of ``step`` within a factor exp(+-``search``)."""
    known = np.isfinite(statures_m) & (statures_m > 0)
    if not known.any():
        return 1.0
    logs = np.log(statures_m[known])
    candidates = np.arange(-search, search + step / 2, step)
    shifted = logs[None, :] + candidates[:, None]  # [C, P]

    def mode(mean_m: float, sigma: float, share: float) -> np.ndarray:
        return np.log(share / sigma) - 0.5 * ((shifted - np.log(mean_m)) / sigma) ** 2

    log_p = np.logaddexp(mode(adult_m, adult_sigma, 1.0 - child_share), mode(child_m, child_sigma, child_share))
    return float(np.exp(candidates[np.argmax(log_p.sum(1))]))
