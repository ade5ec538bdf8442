"""Segment Anything through onnxruntime: the user's exported encoder and decoder (never
downloaded here; docs/masks.md says how to export them).

Encoder: one input, the frame resized so its longer side is 1024 px, normalised with SAM's pixel
mean and standard deviation, zero-padded to [1, 3, 1024, 1024] float32; one output, the
embedding. Decoder: segment-anything's own ONNX export (scripts/export_onnx_model.py), inputs
``image_embeddings, point_coords, point_labels, mask_input, has_mask_input, orig_im_size``,
outputs ``masks`` (logits at the frame's size) and ``iou_predictions`` first. Points are given
in the resized frame, with the padding point (label -1) that export expects without a box.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from glimpse.errors import GlimpseError

SAM_INPUT_SIZE = 1024  # the encoder's square input, pixels
SAM_PIXEL_MEAN = np.array([123.675, 116.28, 103.53])  # RGB, 0..255 (segment-anything)
SAM_PIXEL_STD = np.array([58.395, 57.12, 57.375])
SAM_MASK_INPUT_SIZE = 256  # the decoder's low-resolution mask input side
DECODER_INPUTS = ("image_embeddings", "point_coords", "point_labels", "mask_input", "has_mask_input", "orig_im_size")
PADDING_LABEL = -1.0


@dataclass(frozen=True)
class Embedded:
    embedding: np.ndarray  # the encoder's output
    scale: float  # resized / original pixels
    size: tuple[int, int]  # (height, width) of the original frame


class SamOnnx:
    """One encoder and decoder pair, loaded once (CPU, or CUDA when onnxruntime has it)."""

    def __init__(self, encoder_path: Path, decoder_path: Path):
        import onnxruntime

        for name, path in (("03_masks.sam_encoder_path", encoder_path), ("03_masks.sam_decoder_path", decoder_path)):
            if path is None or not Path(path).is_file():
                raise GlimpseError(f"03_masks.mode=onnx-sam needs {name}: a Segment Anything model exported to ONNX "
                                   f"(docs/masks.md says how); found {path!r}")
        providers = [p for p in ("CUDAExecutionProvider", "CPUExecutionProvider")
                     if p in onnxruntime.get_available_providers()]
        options = onnxruntime.SessionOptions()
        self.encoder = onnxruntime.InferenceSession(str(encoder_path), options, providers=providers)
        self.decoder = onnxruntime.InferenceSession(str(decoder_path), options, providers=providers)
        names = {i.name for i in self.decoder.get_inputs()}
        if not set(DECODER_INPUTS) <= names:
            raise GlimpseError(f"{decoder_path}: a Segment Anything decoder needs inputs {', '.join(DECODER_INPUTS)} "
                               f"(segment-anything's scripts/export_onnx_model.py); found {', '.join(sorted(names))}")

    def embed(self, image: np.ndarray) -> Embedded:
        """image [H, W, 3] uint8 RGB."""
        height, width = image.shape[:2]
        scale = SAM_INPUT_SIZE / max(height, width)
        resized = cv2.resize(image, (int(round(width * scale)), int(round(height * scale))),
                             interpolation=cv2.INTER_LINEAR)
        normalised = (resized.astype(np.float64) - SAM_PIXEL_MEAN) / SAM_PIXEL_STD
        padded = np.zeros((SAM_INPUT_SIZE, SAM_INPUT_SIZE, 3))
        padded[:resized.shape[0], :resized.shape[1]] = normalised
        batch = padded.transpose(2, 0, 1)[None].astype(np.float32)
        embedding = self.encoder.run(None, {self.encoder.get_inputs()[0].name: batch})[0]
        return Embedded(embedding, scale, (height, width))

    def segment(self, embedded: Embedded, points: np.ndarray, labels: np.ndarray) -> np.ndarray:
        """points [N, 2] pixels of the original frame (OpenCV convention), labels [N] (1 = person,
        0 = not) -> [H, W] bool, the mask SAM rates best."""
        # SAM takes pixel indices scaled to the resized frame (its prompt encoder adds the half pixel)
        coords = np.concatenate([points * embedded.scale, np.zeros((1, 2))])[None].astype(np.float32)
        point_labels = np.concatenate([labels, [PADDING_LABEL]])[None].astype(np.float32)
        feeds = {"image_embeddings": embedded.embedding, "point_coords": coords, "point_labels": point_labels,
                 "mask_input": np.zeros((1, 1, SAM_MASK_INPUT_SIZE, SAM_MASK_INPUT_SIZE), np.float32),
                 "has_mask_input": np.zeros(1, np.float32),
                 "orig_im_size": np.array(embedded.size, np.float32)}
        masks, scores = self.decoder.run(None, feeds)[:2]
        return masks[0, int(np.argmax(scores[0]))] > 0.0
