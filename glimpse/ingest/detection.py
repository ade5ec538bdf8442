"""Where people may be in a frame: the regions a person detector proposes for the landmark model."""

from __future__ import annotations

import numpy as np

from glimpse.ingest.blazepose import REGION_GROW, BlazePose, Detections, weighted_nms
from glimpse.ingest.config import IngestConfig
from glimpse.ingest.crop import Region, region_around_box
from glimpse.ingest.onnx_models import OnnxDetector


def detector_regions(model: BlazePose, image: np.ndarray, config: IngestConfig,
                     detector: OnnxDetector | None = None) -> list[Region]:
    """Landmark regions of the detected people: the user's ONNX detector's boxes, or BlazePose's detector on the
    whole frame and on ``detect_tiles``^2 overlapping tiles."""
    if detector is not None:
        boxes, _ = detector(image)
        return [region_around_box(box, REGION_GROW) for box in boxes]
    height, width = image.shape[:2]
    crops = [Region(np.array([(width - 1) / 2, (height - 1) / 2]), float(max(width, height)), 0.0)]
    tiles = config.detect_tiles
    if tiles > 1:
        side = max(width, height) / tiles * (1 + config.detect_tile_overlap)
        for cy in np.linspace(side / 2, height - side / 2, tiles) if height > side else [(height - 1) / 2]:
            for cx in np.linspace(side / 2, width - side / 2, tiles) if width > side else [(width - 1) / 2]:
                crops.append(Region(np.array([cx, cy]), side, 0.0))
    found = [model.detect(image, crop, config.detect_min_score) for crop in crops]
    return weighted_nms(Detections.concatenate(found), config.detect_nms_iou).regions()
