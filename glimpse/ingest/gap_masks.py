"""Masks for the frames a kept person's track missed, from what differs from a fixed camera's background plate.

Where someone walks half hidden behind another person, the landmark model often loses them for a few frames (it
finds nobody, or finds the person in front), and looking again (glimpse.ingest.backfill) finds nothing that looks
like them. Their visible pixels still differ from the background plate, and nobody found in that frame holds them:
between the boxes of the person's masks before and after the gap (interpolated over time, grown by
``gap_mask_box_grow``), the pixels that differ from the plate (glimpse.ingest.foreground) and are no kept person's
label (:func:`kept_only`) are theirs, behind everyone found. A frame gets such a mask only where it holds
``gap_mask_min_share`` to ``gap_mask_max_share`` of the person's mean mask area in the two frames that bracket the
gap: less and they stay hidden (nothing is invented), more and something else (another person the tracks did not
keep, a moved object) is there. Such frames carry no keypoints (all confidence 0; stage 02 interpolates the body
there): the mask says where the person is seen, not how they stand.

The person in front often holds some of those pixels: where the landmark model loses someone walking behind
another, the segmentation of the person in front tends to spread over both. Inside the box, a pixel another
person holds is taken back (:func:`taken_back`) where its colour is more than ``gap_mask_take_ratio`` times as
likely under the colours of the person in the gap (their masks in the two frames around it) as under the colours
of the person holding it (that person's masks in the same two frames), the log of that ratio smoothed over
``gap_mask_colour_smoothing`` of the frame's height first (single pixels do not decide). Clothes of the same colours
leave the pixels where they are.

The plate they are compared with is not the survey's (a per-pixel median over all sampled frames), which shows
a person who stood in one place for most of the video, so that wherever they moved away the background there
"differs" from it: it is the median over the sampled frames of only the pixels no found person covers
(:func:`people_free_plate`, the people's masks grown by ``gap_mask_plate_margin`` of the frame's height).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from math import ceil, floor

import cv2
import numpy as np

from glimpse.ingest.config import IngestConfig
from glimpse.ingest.crop import box_centre
from glimpse.ingest.foreground import unexplained_foreground
from glimpse.ingest.report import PersonTrack


@dataclass(frozen=True)
class GapFrame:
    """A frame inside a person's gap: the frames seen just before and after it, and how far in it lies (0..1)."""

    frame_id: int
    before: int
    after: int
    fraction: float


def gap_frames(frames: list[int], max_frames: int) -> list[GapFrame]:
    """The frames missing between consecutive ``frames`` (sorted scene frame ids, consecutive ids being
    consecutive frames) of gaps of at most ``max_frames`` frames."""
    out = []
    for before, after in zip(frames, frames[1:]):
        missing = after - before - 1
        if 0 < missing <= max_frames:
            out.extend(GapFrame(f, before, after, (f - before) / (after - before)) for f in range(before + 1, after))
    return out


def interpolated_box(before: np.ndarray, after: np.ndarray, fraction: float, grow: float) -> np.ndarray:
    """(4,) x0, y0, x1, y1: the box ``fraction`` of the way from box ``before`` to box ``after`` (pixels), its sides
    times ``grow`` about its centre."""
    box = (1.0 - fraction) * np.asarray(before, float) + fraction * np.asarray(after, float)
    centre, half = box_centre(box), grow * (box[2:] - box[:2]) / 2
    return np.concatenate([centre - half, centre + half])


def box_pixels(box: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """[H, W] bool: the pixels whose centres lie in ``box`` (x0, y0, x1, y1)."""
    ys, xs = np.arange(shape[0])[:, None], np.arange(shape[1])[None, :]
    return (xs >= box[0]) & (xs <= box[2]) & (ys >= box[1]) & (ys <= box[3])


def people_free_plate(samples: np.ndarray, people: np.ndarray, plate: np.ndarray, margin_px: int,
                      rows_at_once: int = 64) -> np.ndarray:
    """[H, W, 3] uint8: the per-pixel median of ``samples`` [N, H, W, 3] uint8 over the frames where ``people``
    [N, H, W] bool (someone found) is false at that pixel, after growing it by ``margin_px`` pixels (the masks'
    edges); ``plate`` [H, W, 3] where every sample has someone there. Computed ``rows_at_once`` rows at a time."""
    if margin_px > 0:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin_px + 1,) * 2)
        people = np.stack([cv2.dilate(p.astype(np.uint8), kernel) > 0 for p in people])
    out = plate.copy()
    for top in range(0, samples.shape[1], rows_at_once):
        rows = slice(top, top + rows_at_once)
        free = ~people[:, rows]
        values = np.where(free[..., None], samples[:, rows].astype(np.float32), np.nan)
        seen = free.any(0)
        with np.errstate(all="ignore"):
            median = np.nanmedian(values[:, seen], axis=0)
        out[rows][seen] = np.round(median).astype(np.uint8)
    return out


def kept_only(labels: np.ndarray, kept: list[int]) -> np.ndarray:
    """[H, W] uint16: ``labels`` with every label not in ``kept`` set to 0 (nobody). A track dropped after tracking
    (too short, too small) is no one in the scene; often it was the person the kept track lost, found for a few
    frames under a new id, so its pixels are left to the gap masks."""
    return np.where(np.isin(labels, kept), labels, 0).astype(labels.dtype)


def colour_histogram(image: np.ndarray, mask: np.ndarray, bins: int) -> np.ndarray:
    """[bins ** 3] float: the RGB colours of ``image`` [H, W, 3] uint8 under ``mask`` [H, W] bool, ``bins`` per
    channel, one count added to every bin (a colour not seen stays possible), normalised to unit sum."""
    counts = np.bincount(colour_bins(image[mask], bins), minlength=bins ** 3).astype(float) + 1.0
    return counts / counts.sum()


def colour_bins(pixels: np.ndarray, bins: int) -> np.ndarray:
    """[...] int: the RGB histogram bin of each of ``pixels`` [..., 3] uint8, ``bins`` per channel."""
    index = pixels.astype(np.int64) * bins // 256
    return (index[..., 0] * bins + index[..., 1]) * bins + index[..., 2]


def colour_log_ratio(colour_index: np.ndarray, mine: np.ndarray, theirs: np.ndarray, sigma_px: float) -> np.ndarray:
    """[H, W] float32: log p(colour | ``mine``) - log p(colour | ``theirs``) at each pixel of an image whose colours'
    bins are ``colour_index`` [H, W] (:func:`colour_bins`), both [bins ** 3] colour histograms
    (:func:`colour_histogram`), smoothed by a Gaussian of ``sigma_px``."""
    ratio = (np.log(mine)[colour_index] - np.log(theirs)[colour_index]).astype(np.float32)
    return cv2.GaussianBlur(ratio, (0, 0), sigma_px) if sigma_px > 0 else ratio


def taken_back(image: np.ndarray, labels: np.ndarray, box: np.ndarray, mine: np.ndarray,
               theirs: dict[int, np.ndarray | None], ratio: float, sigma_px: float) -> np.ndarray:
    """[H, W] bool: the pixels inside ``box`` held by a label of ``theirs`` (label -> its colour histogram) whose
    colour is more than ``ratio`` times as likely under ``mine`` as under that label's (:func:`colour_log_ratio`).
    Labels whose histogram is None keep their pixels. Computed on the box grown by the smoothing's reach."""
    height, width = labels.shape
    taken = np.zeros(labels.shape, bool)
    y0, y1 = max(0, ceil(box[1])), min(height - 1, floor(box[3]))  # the rows and columns of the box's pixels
    x0, x1 = max(0, ceil(box[0])), min(width - 1, floor(box[2]))
    if y0 > y1 or x0 > x1:
        return taken
    margin = ceil(3 * sigma_px)  # the smoothing's reach
    rows, cols = slice(max(0, y0 - margin), y1 + 1 + margin), slice(max(0, x0 - margin), x1 + 1 + margin)
    held_by = labels[rows, cols]
    inside = box_pixels(np.asarray(box, float) - [cols.start, rows.start] * 2, held_by.shape)
    colour_index = colour_bins(image[rows, cols], round(len(mine) ** (1 / 3)))
    for label, histogram in theirs.items():
        held = inside & (held_by == label)
        if histogram is not None and held.any():
            log_ratio = colour_log_ratio(colour_index, mine, histogram, sigma_px)
            taken[rows, cols] |= held & (log_ratio > np.log(ratio))
    return taken


@dataclass(frozen=True)
class Sighting:
    """A person's mask in a frame just before or after a gap in their track (tracking size)."""

    box: np.ndarray  # (4,) x0, y0, x1, y1 pixels
    area: int  # pixels
    colours: np.ndarray  # [bins ** 3] colour histogram (:func:`colour_histogram`)


def sightings_in(image: np.ndarray, labels: np.ndarray, frame_id: int, bins: int) -> dict[tuple[int, int], Sighting]:
    """(label, ``frame_id``) -> the box, area and colours (``bins`` per channel) of each label's mask in ``labels``
    [H, W] (0: nobody) over ``image`` [H, W, 3] uint8."""
    out = {}
    for label in np.unique(labels[labels > 0]):
        mask = labels == label
        out[int(label), frame_id] = Sighting(mask_box(mask), int(mask.sum()), colour_histogram(image, mask, bins))
    return out


def mean_colours(gap: GapFrame, label: int, sightings: dict[tuple[int, int], Sighting]) -> np.ndarray | None:
    """The mean colour histogram of ``label``'s masks in the frames around ``gap``; None when neither shows them."""
    seen = [sightings[label, f].colours for f in (gap.before, gap.after) if (label, f) in sightings]
    return np.mean(seen, axis=0) if seen else None


def gap_mask(image: np.ndarray, plate: np.ndarray, labels: np.ndarray, box: np.ndarray, expected_area: float,
             config: IngestConfig, taken: np.ndarray | None = None) -> np.ndarray | None:
    """[H, W] bool: the pixels of ``image`` [H, W, 3] uint8 inside ``box`` that differ from ``plate`` and that no
    label of ``labels`` [H, W] (0: nobody) holds, or that are ``taken`` [H, W] bool (:func:`taken_back`) from
    the label holding them, cleaned as the foreground is; None when they cover less than ``gap_mask_min_share``
    or more than ``gap_mask_max_share`` of ``expected_area`` (pixels)."""
    found = labels > 0
    if taken is not None:
        found &= ~taken
    mine = unexplained_foreground(image, plate, found, config).astype(bool) & ~found & box_pixels(box, labels.shape)
    share = mine.sum() / max(expected_area, 1.0)
    return mine if config.gap_mask_min_share <= share <= config.gap_mask_max_share else None


def mask_box(mask: np.ndarray) -> np.ndarray:
    """(4,) x0, y0, x1, y1 pixel centres: the box of the True pixels of ``mask`` [H, W] (some are)."""
    ys, xs = np.nonzero(mask)
    return np.array([xs.min(), ys.min(), xs.max(), ys.max()], float)


def with_mask_frames(person: PersonTrack, boxes: dict[int, np.ndarray]) -> PersonTrack:
    """``person`` with the frames of ``boxes`` (frame id -> (4,) box, scene pixels) added in order: a mask (in the
    labels) and no keypoints (confidence 0); ``masks_from_foreground`` lists them."""
    if not boxes:
        return person
    frames = sorted([*person.frames, *boxes])
    row = {frame_id: k for k, frame_id in enumerate(person.frames)}

    def merged(values: np.ndarray, added: dict[int, np.ndarray]) -> np.ndarray:
        return np.stack([values[row[f]] if f in row else added[f] for f in frames])

    def empty(channels: int) -> dict[int, np.ndarray]:
        return {f: np.zeros((person.keypoints.shape[1], channels)) for f in boxes}

    return replace(person, frames=frames, keypoints=merged(person.keypoints, empty(3)),
                   relative3d=merged(person.relative3d, empty(4)), boxes=merged(person.boxes, boxes),
                   masks_from_foreground=sorted(boxes))
