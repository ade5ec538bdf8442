"""Tiny ONNX stand-ins for the models users bring to the ingest, in rtmlib/mmdeploy layouts, exported from torch
(no weights): a detector that boxes the bright part of its input (mmdeploy's end-to-end ``dets``/``labels``) and
SimCC or heatmap pose models whose every keypoint is the brightest pixel of their input."""

from __future__ import annotations

from pathlib import Path

import torch

POSE_H, POSE_W = 64, 48
DET_SIZE = 96


class _BrightBoxDetector(torch.nn.Module):
    """dets [1, 1, 5]: the box of input pixels nearer the brightest than the mean (normalised or not, grey
    letterbox padding stays out); labels [1, 1]."""

    def forward(self, x: torch.Tensor):
        intensity = x.mean(1)[0]
        bright = intensity > (intensity.amax() + intensity.mean()) / 2
        cols, rows = bright.any(0).float(), bright.any(1).float()
        x0, y0 = torch.argmax(cols), torch.argmax(rows)
        x1 = cols.shape[0] - 1 - torch.argmax(torch.flip(cols, [0]))
        y1 = rows.shape[0] - 1 - torch.argmax(torch.flip(rows, [0]))
        box = torch.stack([x0, y0, x1, y1]).float()
        dets = torch.cat([box, torch.ones(1)])[None, None]
        return dets, torch.zeros(1, 1, dtype=torch.int64)


class _BrightestPointPose(torch.nn.Module):
    """Every one of ``count`` keypoints at the brightest input pixel: SimCC (split ratio 2) or 4x heatmaps."""

    def __init__(self, count: int, simcc: bool):
        super().__init__()
        self.count, self.simcc = count, simcc

    def forward(self, x: torch.Tensor):
        intensity = x.mean(1)  # [1, H, W]
        if self.simcc:
            columns = intensity.amax(1).repeat_interleave(2, dim=-1)  # [1, 2W]
            rows = intensity.amax(2).repeat_interleave(2, dim=-1)  # [1, 2H]
            return columns[:, None].expand(1, self.count, -1), rows[:, None].expand(1, self.count, -1)
        heat = torch.nn.functional.avg_pool2d(intensity[:, None], 4)  # [1, 1, H/4, W/4]
        return heat.expand(1, self.count, -1, -1)


def _export(module: torch.nn.Module, shape: tuple[int, ...], path: Path, outputs: list[str]) -> str:
    torch.onnx.export(module, (torch.zeros(shape),), str(path), dynamo=False, input_names=["input"],
                      output_names=outputs)
    return str(path)


def bright_box_detector(path: Path) -> str:
    return _export(_BrightBoxDetector(), (1, 3, DET_SIZE, DET_SIZE), path, ["dets", "labels"])


def brightest_point_pose(path: Path, count: int = 17, simcc: bool = True) -> str:
    outputs = ["simcc_x", "simcc_y"] if simcc else ["heatmaps"]
    return _export(_BrightestPointPose(count, simcc), (1, 3, POSE_H, POSE_W), path, outputs)
