"""Masks snapped to the frame's edges (glimpse.ingest.mask_snap): the colour guided filter against a direct
transcription of He et al.'s definition (a ridge regression of the mask on the colours in every window, the
window models averaged at each pixel), and what snapping does to a mask whose edge is off the body's."""

from __future__ import annotations

import numpy as np

from glimpse.ingest.mask_snap import guided_filter, snapped_masks


def _reflected(values: np.ndarray, radius: int) -> np.ndarray:
    """``values`` [H, W, ...] padded by ``radius`` on both spatial axes, mirrored with the edge repeated."""
    pad = [(radius, radius), (radius, radius)] + [(0, 0)] * (values.ndim - 2)
    return np.pad(values, pad, mode="symmetric")


def _guided_by_definition(guide: np.ndarray, source: np.ndarray, radius: int, eps: float) -> np.ndarray:
    """For each window centre k: (a_k, b_k) minimising sum_i (a_k . I_i + b_k - p_i)^2 + eps |a_k|^2 over the
    window (solved as a least-squares problem with eps rows appended); then at each pixel the mean of a_k and
    b_k over the windows around it, applied to its own colour."""
    height, width = source.shape
    size = 2 * radius + 1
    guide_pad, source_pad = _reflected(guide, radius), _reflected(source, radius)
    slopes, offsets = np.zeros((height, width, 3)), np.zeros((height, width))
    for y in range(height):
        for x in range(width):
            colours = guide_pad[y:y + size, x:x + size].reshape(-1, 3).astype(np.float64)
            values = source_pad[y:y + size, x:x + size].reshape(-1).astype(np.float64)
            n = len(values)
            design = np.vstack([np.c_[colours, np.ones(n)], np.c_[np.sqrt(eps * n) * np.eye(3), np.zeros(3)]])
            target = np.r_[values, np.zeros(3)]
            solution = np.linalg.lstsq(design, target, rcond=None)[0]
            slopes[y, x], offsets[y, x] = solution[:3], solution[3]
    slopes_pad, offsets_pad = _reflected(slopes, radius), _reflected(offsets, radius)
    out = np.zeros((height, width))
    for y in range(height):
        for x in range(width):
            mean_slope = slopes_pad[y:y + size, x:x + size].reshape(-1, 3).mean(0)
            out[y, x] = mean_slope @ guide[y, x] + offsets_pad[y:y + size, x:x + size].mean()
    return out


def test_the_guided_filter_is_he_et_al_s_definition() -> None:
    rng = np.random.default_rng(0)
    guide = rng.random((9, 11, 3)).astype(np.float32)
    source = (rng.random((9, 11)) > 0.5).astype(np.float32)
    for radius, eps in ((1, 1e-3), (2, 1e-2)):
        filtered = guided_filter(guide, source[None], radius, eps)[0]
        np.testing.assert_allclose(filtered, _guided_by_definition(guide, source, radius, eps), atol=2e-4)
        assert filtered.dtype == np.float32


def test_a_mask_edge_off_the_body_moves_onto_it_and_people_stay_apart() -> None:
    """A red body on a blue wall; the mask reaches 3 px past the body's edge (the soft segmentation): snapped with a
    4 px radius, it holds fewer than half as many wall pixels and no fewer body pixels (the filter moves an edge
    towards the colour edge; it does not jump to it). A second person's mask beside it stays theirs; a sliver on a
    flat wall is kept as it was."""
    frame = np.zeros((40, 60, 3), np.uint8)
    frame[:] = (30, 40, 200)
    frame[5:35, 10:25] = (210, 40, 30)  # the first body
    frame[5:35, 35:50] = (40, 190, 60)  # the second, beside it
    first = np.zeros((40, 60), bool)
    first[5:35, 10:28] = True  # 3 px too wide on the right
    second = np.zeros((40, 60), bool)
    second[5:35, 33:50] = True  # 2 px too wide on the left
    snapped_first, snapped_second = snapped_masks(frame, [first, second], radius=4, eps=1e-3)
    body_first, body_second = np.zeros_like(first), np.zeros_like(second)
    body_first[5:35, 10:25], body_second[5:35, 35:50] = True, True
    for mask, snapped, body in ((first, snapped_first, body_first), (second, snapped_second, body_second)):
        assert (snapped & ~body).sum() < 0.5 * (mask & ~body).sum() and not (body & ~snapped).any()
    assert not (snapped_first & snapped_second).any()
    sliver = np.zeros((40, 60), bool)
    sliver[20, 55] = True  # one pixel on the flat wall: filtered away, so kept
    assert np.array_equal(snapped_masks(frame, [sliver], radius=4, eps=1e-3)[0], sliver)
    assert snapped_masks(frame, [first], radius=0, eps=1e-3)[0] is first


def test_the_ingest_snaps_segmented_masks_and_keeps_those_from_the_plate(tmp_path) -> None:
    """What the ingest writes: the mask from the segmentation snapped (fewer wall pixels), the one a track's gap got
    from the background plate (already at the pixels' own edges) as it was, and the two still apart."""
    from dataclasses import replace
    from types import SimpleNamespace

    from glimpse.ingest.config import load_ingest_config
    from glimpse.ingest.report import PersonTrack
    from glimpse.ingest.stage import _write_masks
    from glimpse.io.images import read_mask
    from glimpse.scene.writer import SceneWriter

    frame = np.zeros((40, 60, 3), np.uint8)
    frame[:] = (30, 40, 200)
    frame[5:35, 10:25] = (210, 40, 30)
    frame[5:35, 35:50] = (40, 190, 60)
    labels = np.zeros((40, 60), np.uint16)
    labels[5:35, 10:28] = 1  # segmented, 3 px too wide
    labels[5:35, 33:50] = 2  # from the plate
    writer = SceneWriter(tmp_path / "scene", "snap", 10.0, "static")
    writer.frame(0, frame)
    empty = (np.zeros((1, 17, 3)), np.zeros((1, 17, 4)), np.zeros((1, 4)), [], [])
    people = [PersonTrack("p0", 1, [0], *empty), PersonTrack("p1", 2, [0], *empty, masks_from_foreground=[0])]
    config = replace(load_ingest_config(), mask_snap_radius=4 / 60)
    _write_masks(writer, people, lambda frame_id: labels, SimpleNamespace(width=60, height=40), config)
    segmented, from_plate = (read_mask(writer.written(f"humans/{pid}/masks/000000.png")) for pid in ("p0", "p1"))
    body = np.zeros((40, 60), bool)
    body[5:35, 10:25] = True
    assert np.array_equal(from_plate, labels == 2)
    assert (segmented & ~body).sum() < 0.5 * ((labels == 1) & ~body).sum() and not (body & ~segmented).any()
    assert not (segmented & from_plate).any()
