"""Square, rotated regions of an image and the affine maps between a region and its crop.

A :class:`Region` is a square in image pixels: its centre (x, y), its side and its rotation (radians; the
crop's x axis points along ``(cos a, sin a)`` in the image, y down). Pixel centres sit at integer coordinates
(the scene format's convention). BlazePose's regions follow MediaPipe's rule: the centre is one alignment point
(the mid hip), the side twice the distance to the second (the body's scale point), grown by ``grow``, and the
rotation turns the line between them upright.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

UPRIGHT_RAD = np.pi / 2  # the direction (image y down) that the alignment line is turned to


@dataclass(frozen=True)
class Region:
    centre: np.ndarray  # (2,) pixels
    side: float  # pixels
    angle: float  # radians

    def box(self) -> np.ndarray:
        """(4,) x0, y0, x1, y1 of the axis-aligned box that holds the rotated square."""
        corners = crop_to_image(self, np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]]), 1)
        return np.concatenate([corners.min(0), corners.max(0)])


def crop_affine(region: Region, crop_size: int) -> np.ndarray:
    """[2, 3] affine map from crop pixels (0 .. crop_size - 1, centres) to image pixels."""
    scale = region.side / crop_size
    c, s = np.cos(region.angle), np.sin(region.angle)
    linear = scale * np.array([[c, -s], [s, c]])
    offset = np.asarray(region.centre, float) + linear @ np.full(2, 0.5 - crop_size / 2)
    return np.concatenate([linear, offset[:, None]], axis=1)


def crop_image(image: np.ndarray, region: Region, crop_size: int) -> np.ndarray:
    """The region of ``image`` ([H, W, C]) resampled (bilinear) to [crop_size, crop_size, C]; outside is zero."""
    return cv2.warpAffine(image, crop_affine(region, crop_size), (crop_size, crop_size),
                          flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def crop_to_image(region: Region, points: np.ndarray, crop_size: int) -> np.ndarray:
    """[N, 2] crop pixel coordinates -> [N, 2] image pixel coordinates."""
    affine = crop_affine(region, crop_size)
    return points @ affine[:, :2].T + affine[:, 2]


def normalized_to_crop(points: np.ndarray, crop_size: int) -> np.ndarray:
    """MediaPipe's normalised crop coordinates ([0, 1] across the crop's edges) -> crop pixel centres."""
    return points * crop_size - 0.5


def paste_to_image(crop: np.ndarray, region: Region, width: int, height: int) -> np.ndarray:
    """A [S, S] float map over the region's crop, resampled (bilinear) onto an [height, width] image; zero elsewhere."""
    return cv2.warpAffine(crop.astype(np.float32), crop_affine(region, crop.shape[0]), (width, height),
                          flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def region_from_alignment(centre: np.ndarray, scale_point: np.ndarray, grow: float) -> Region:
    """MediaPipe's alignment rule: centre at ``centre``, side 2 |scale_point - centre| * grow, rotated so that
    the centre -> scale_point line points up in the crop."""
    delta = np.asarray(scale_point, float) - np.asarray(centre, float)
    angle = UPRIGHT_RAD - np.arctan2(-delta[1], delta[0])
    angle = (angle + np.pi) % (2 * np.pi) - np.pi
    return Region(np.asarray(centre, float), 2.0 * float(np.hypot(*delta)) * grow, float(angle))


def box_centre(box: np.ndarray) -> np.ndarray:
    """(2,) pixels: the centre of an axis-aligned box (x0, y0, x1, y1)."""
    return (box[:2] + box[2:]) / 2


def region_around_box(box: np.ndarray, grow: float) -> Region:
    """An upright square around an axis-aligned box (x0, y0, x1, y1), its longer side grown by ``grow``."""
    x0, y0, x1, y1 = box
    return Region(box_centre(np.asarray(box)), max(x1 - x0, y1 - y0) * grow, 0.0)


def outside_image(points: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """[N] bool: which of ``points`` [N, 2] (pixels, centres at integers) lie outside an image of ``shape`` (H, W),
    whose pixels cover -0.5 .. W - 0.5 and -0.5 .. H - 0.5."""
    height, width = shape
    x, y = points[:, 0], points[:, 1]
    return (x < -0.5) | (x > width - 0.5) | (y < -0.5) | (y > height - 0.5)
