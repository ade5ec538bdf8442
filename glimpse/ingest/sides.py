"""Which side is left, kept consistent along a track.

A pose model can call a person's left their right for a few frames: BlazePose does so for a person who faces the
camera with their arms at rest (front and back have one outline), takes them for someone seen from behind and
exchanges every left/right pair, while the frames before and after, arms moving, it gets them right. Smoothing
and stage 02's fit cannot repair that: a body fitted to such keypoints turns round and back.

Over the whole track at once, a Viterbi pass picks one state per frame, labels as given or every left/right pair
exchanged, minimising, in torso lengths:

- **continuity**: between consecutive frames of the track, the mean displacement of the left/right joints both
  frames hold under the two frames' labels (a left shoulder that jumps onto the right one's place costs the
  jump; a person turning round moves continuously and costs the same either way), and
- **trust in the model**: every exchanged frame costs ``keep_weight``, so a run the model labels one way is
  only exchanged when the jumps at its ends cost more, and a track labelled consistently is left as it is.

So the shorter runs between such jumps take the labels of the longer ones around them. Nothing here knows
which way the person faces: a model that is wrong for most of a track stays wrong.

A frame's exchange applies to the 2D keypoints and to the model's metric 3D landmarks; in 3D the depth is also
mirrored about the hips when the exchanged skeleton would otherwise be a mirror image of a body (its nose on
the side its chest's normal points away from).

**The legs alone.** A side-on walker's two legs look alike: the model tends to give the front leg one side's
name whichever leg it is, so its labels change when the swinging foot passes the planted one, between two frames
of a 10 fps video, without any jump (each leg's label then moves half a stride, as the two real feet do between
them). Its run on the mirrored crop names the front leg the other way (glimpse.ingest.blazepose.
legs_named_otherwise): where the two runs disagree, the legs' names are a guess. A second pass over the track
(:func:`legs_to_exchange`, static camera only) then decides them by a **planted foot**: a walker has a foot on
the ground, still in the image of a static camera, between every two frames; a frame pair costs the smaller of
the two ankles' displacements under its labels. Exchanging a frame the runs agree on costs ``keep_weight``; one
whose mirrored runs mostly disputed the names, nothing.

A foot stays planted for longer than two frames (about 0.6 s of a 1 s stride), and where the feet pass each
other, between two frames, both ankles lie close together and two frames alone hardly tell which one stayed. So
every two frames within a window (``window`` frame ids apart at most: ``legs_planted_window_s`` of the video)
cost their planted foot's displacement (the farther apart, the less: a foot is likelier to have lifted over
more frames), and the pass keeps the labels of the last ``window`` frames as its state: the frames before the
crossing, where the feet were apart, then decide it.
"""

from __future__ import annotations

import numpy as np

from glimpse.ingest.config import IngestConfig

LEGS_WINDOW_MAX_FRAMES = 10  # the legs' pass keeps 2^window histories per frame: 1024 at most

# COCO-17 left/right pairs: eyes, ears, shoulders, elbows, wrists, hips, knees, ankles
COCO17_SIDE_PAIRS = ((1, 2), (3, 4), (5, 6), (7, 8), (9, 10), (11, 12), (13, 14), (15, 16))
COCO17_LEG_PAIRS = ((13, 14), (15, 16))  # knees, ankles
COCO17_ANKLES = (15, 16)
COCO17_NOSE = 0
SHOULDERS, HIPS = (5, 6), (11, 12)
COCO17_EXCHANGE = np.arange(17)
COCO17_LEG_EXCHANGE = np.arange(17)
for _left, _right in COCO17_SIDE_PAIRS:
    COCO17_EXCHANGE[_left], COCO17_EXCHANGE[_right] = _right, _left
for _left, _right in COCO17_LEG_PAIRS:
    COCO17_LEG_EXCHANGE[_left], COCO17_LEG_EXCHANGE[_right] = _right, _left


def torso_axes(keypoints: np.ndarray) -> np.ndarray:
    """[T, 17, 3] COCO-17 keypoints (x, y, confidence; 0 = missing) -> [T, 2] pixels from the mid hip to the mid
    shoulder, NaN where a shoulder or a hip is missing."""
    complete = (keypoints[:, list(SHOULDERS + HIPS), 2] > 0).all(1)
    up = keypoints[:, list(SHOULDERS), :2].mean(1) - keypoints[:, list(HIPS), :2].mean(1)
    return np.where(complete[:, None], up, np.nan)


def torso_lengths(keypoints: np.ndarray) -> np.ndarray:
    """[T, 17, 3] COCO-17 keypoints -> [T] pixels from the mid hip to the mid shoulder, NaN where a shoulder or a
    hip is missing (:func:`torso_axes`)."""
    return np.linalg.norm(torso_axes(keypoints), axis=1)


def side_displacements(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Mean pixel displacement from [17, 3] frame ``a`` to frame ``b`` of the left/right joints both hold, with
    b's labels kept and exchanged (summed over a pair's two joints, averaged over the pairs); (0, 0) when they
    share no pair."""
    kept, exchanged, count = 0.0, 0.0, 0
    for left, right in COCO17_SIDE_PAIRS:
        if min(a[left, 2], a[right, 2], b[left, 2], b[right, 2]) <= 0:
            continue
        kept += np.linalg.norm(a[left, :2] - b[left, :2]) + np.linalg.norm(a[right, :2] - b[right, :2])
        exchanged += np.linalg.norm(a[left, :2] - b[right, :2]) + np.linalg.norm(a[right, :2] - b[left, :2])
        count += 1
    return (kept / count, exchanged / count) if count else (0.0, 0.0)


def _torso_scale(keypoints: np.ndarray) -> np.ndarray:
    """[T, 17, 3] -> [T] pixels: each frame's torso length, the track's median where a frame has none (1 if no
    frame has one)."""
    torso = torso_lengths(keypoints)
    return np.where(np.isfinite(torso), torso, np.nanmedian(torso) if np.isfinite(torso).any() else 1.0)


def sides_to_exchange(keypoints: np.ndarray, keep_weight: float) -> np.ndarray:
    """[T, 17, 3] one track's COCO-17 keypoints in frame order -> [T] bool: the frames whose left/right pairs
    are to be exchanged (module docstring; ``keep_weight`` in torso lengths per exchanged frame)."""
    count = len(keypoints)
    if count == 0:
        return np.zeros(0, bool)
    scale = _torso_scale(keypoints)
    steps = np.zeros((count, 2, 2))
    for t in range(1, count):
        kept, exchanged = side_displacements(keypoints[t - 1], keypoints[t])
        steps[t] = np.array([[kept, exchanged], [exchanged, kept]]) / max(scale[t - 1], scale[t], 1e-6)
    return _cheapest_histories(np.tile([0.0, keep_weight], (count, 1)), steps[:, None])


def legs_to_exchange(frames: np.ndarray, keypoints: np.ndarray, disputed: np.ndarray, keep_weight: float,
                     dispute_share: float, window: int = 1, discount: float = 0.0) -> np.ndarray:
    """frames [T] increasing frame ids and [T, 17, 3] COCO-17 keypoints of one track, disputed [T] the share of
    the model's mirrored runs that named the legs the other way -> [T] bool: the frames whose knees and ankles
    are to be exchanged (module docstring, "The legs alone"). Exchanging a frame costs nothing where at least
    ``dispute_share`` of its mirrored runs disputed the names (the names then come from the model's habit, not
    from the image: they turn with the crop), else ``keep_weight`` torso lengths; every two frames at most
    ``window`` frame ids and ``window`` track frames apart that both hold both ankles cost the smaller of the
    ankles' displacements between them under their two labels, in torso lengths, times d ** -``discount`` for
    frames d apart (a foot planted over more frames is likelier to have lifted). Ties keep the names."""
    count = len(keypoints)
    if count == 0:
        return np.zeros(0, bool)
    scale = _torso_scale(keypoints)
    unary = np.stack([np.zeros(count), np.where(np.asarray(disputed) >= dispute_share, 0.0, keep_weight)], 1)
    ankles, exchanged = list(COCO17_ANKLES), list(COCO17_ANKLES[::-1])
    held = (keypoints[:, ankles, 2] > 0).all(1)
    # pairs[t, d - 1, state of frame t - d, state of frame t]: the planted foot's displacement between them
    pairs = np.zeros((count, window, 2, 2))
    for t in range(1, count):
        for back in range(1, min(window, t) + 1):
            before, now = keypoints[t - back], keypoints[t]
            if frames[t] - frames[t - back] > window or not (held[t - back] and held[t]):
                continue
            for previous, order_before in enumerate((ankles, exchanged)):
                for state, order_now in enumerate((ankles, exchanged)):
                    moved = np.linalg.norm(now[order_now, :2] - before[order_before, :2], axis=1)
                    pairs[t, back - 1, previous, state] = (moved.min() / max(scale[t - back], scale[t], 1e-6)
                                                           / back ** discount)
    return _cheapest_histories(unary, pairs)


def _cheapest_histories(unary: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """Viterbi over the states of the last W frames: unary [T, 2] costs of each frame's two states (0: labels
    kept, 1: exchanged), pairs [T, W, 2, 2] costs between frame t - d's state and frame t's (d = 1 .. W; those
    with t - d < 0 name no frame and are not counted) -> [T] bool, the states of the cheapest path (ties keep the
    labels). A history is an integer whose bit j is the state of frame t - j."""
    count, window = pairs.shape[:2]
    pairs = np.where((np.arange(count)[:, None] >= np.arange(1, window + 1))[:, :, None, None], pairs, 0.0)
    histories = np.arange(2 ** window)
    bits = (histories[:, None] >> np.arange(window)) & 1  # [H, W]: bit j of each history
    cost = np.where(histories < 2, unary[0][histories % 2], np.inf)  # frame 0: no frames before it
    back = np.zeros((count, 2 ** window), int)
    # history g after frame t comes from the two histories h whose bits 0 .. W - 2 are g's bits 1 .. W - 1 (the
    # oldest state, bit W - 1 of h, is forgotten) by frame t's state s = bit 0 of g
    newest = histories & 1
    sources = (histories >> 1)[None, :] | (np.arange(2)[:, None] << (window - 1))  # [2, H]: oldest bit 0, 1
    for t in range(1, count):
        # from history h (frame t - 1 first) by state s: frame t - d's state is bit d - 1 of h
        step = unary[t][None, :] + pairs[t, np.arange(window)[None, :, None], bits[:, :, None],
                                         np.arange(2)[None, None, :]].sum(1)  # [H, 2]
        total = (cost[:, None] + step)[sources, newest[None, :]]  # [2, H]
        oldest = np.argmin(total, axis=0)  # ties: the source whose forgotten state kept the labels
        cost = total[oldest, histories]
        back[t] = sources[oldest, histories]
    states = np.zeros(count, int)
    history = int(np.argmin(cost))
    for t in range(count - 1, -1, -1):
        states[t] = history & 1
        history = back[t, history]
    return states.astype(bool)


def exchange_legs(keypoints: np.ndarray, relative3d: np.ndarray, exchange: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Copies of [T, 17, 3] keypoints and [T, 17, 4] relative3d with the knees and the ankles exchanged in the
    frames ``exchange`` [T] bool."""
    keypoints, relative3d = keypoints.copy(), relative3d.copy()
    keypoints[exchange] = keypoints[exchange][:, COCO17_LEG_EXCHANGE]
    relative3d[exchange] = relative3d[exchange][:, COCO17_LEG_EXCHANGE]
    return keypoints, relative3d


def exchange_sides(keypoints: np.ndarray, relative3d: np.ndarray, exchange: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Copies of [T, 17, 3] keypoints and [T, 17, 4] relative3d (metres from the mid hip, image axes: x right,
    y down, z away from the camera; then a confidence) with the left/right pairs exchanged in the frames
    ``exchange`` [T] bool; there the 3D depth is mirrored too where the exchange made the skeleton a mirror
    image of a body (:func:`mirrored_3d`)."""
    keypoints, relative3d = keypoints.copy(), relative3d.copy()
    keypoints[exchange] = keypoints[exchange][:, COCO17_EXCHANGE]
    relative3d[exchange] = relative3d[exchange][:, COCO17_EXCHANGE]
    flip = exchange & mirrored_3d(relative3d)
    relative3d[flip, :, 2] = -relative3d[flip, :, 2]
    return keypoints, relative3d


def mirrored_3d(relative3d: np.ndarray) -> np.ndarray:
    """[T, 17, 4] -> [T] bool: skeletons whose nose lies behind the chest's normal ((left - right) x up, the way a
    body with these labels faces), mirror images of a body; False where a shoulder, a hip or the nose is missing."""
    points, found = relative3d[..., :3], relative3d[..., 3] > 0
    complete = found[:, list(SHOULDERS + HIPS) + [COCO17_NOSE]].all(1)
    shoulders = points[:, list(SHOULDERS)].mean(1)
    up = shoulders - points[:, list(HIPS)].mean(1)
    across = sum(points[:, left] - points[:, right] for left, right in (SHOULDERS, HIPS))
    normal = np.cross(across, up)
    return complete & (np.einsum("ti,ti->t", normal, points[:, COCO17_NOSE] - shoulders) < 0)


def consistent_sides(frames: np.ndarray, keypoints: np.ndarray, relative3d: np.ndarray, legs_disputed: np.ndarray,
                     static: bool, fps: float, config: IngestConfig
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One track's frames [T] (increasing ids at ``fps``), keypoints [T, 17, 3], relative3d [T, 17, 4] and legs'
    disputes [T] -> (keypoints, relative3d, [T] bool frames whose left and right were exchanged, [T] bool frames
    whose legs were): left and right kept consistent along the track (``sides_consistent``), and on a ``static``
    camera the legs' names decided by a planted foot over ``legs_planted_window_s`` (``legs_consistent``)."""
    exchange = np.zeros(len(frames), bool)
    if config.sides_consistent:
        exchange = sides_to_exchange(keypoints, config.sides_keep_weight)
        keypoints, relative3d = exchange_sides(keypoints, relative3d, exchange)
    legs = np.zeros(len(frames), bool)
    if config.legs_consistent and static:
        window = int(np.clip(round(config.legs_planted_window_s * fps), 1, LEGS_WINDOW_MAX_FRAMES))
        legs = legs_to_exchange(frames, keypoints, legs_disputed, config.legs_keep_weight, config.legs_dispute_share,
                                window, config.legs_planted_discount)
        keypoints, relative3d = exchange_legs(keypoints, relative3d, legs)
    return keypoints, relative3d, exchange, legs
