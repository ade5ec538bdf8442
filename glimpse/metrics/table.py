"""Metrics tables: per-frame PSNR / SSIM / LPIPS, their means, written as JSON and Markdown.

Every table states its protocol (mask, background colour, LPIPS network and scale, frames
used, and the fixed PSNR / SSIM definitions), so two tables can be compared honestly.
Units: PSNR in dB (data range 1), SSIM in [-1, 1] (1 = equal), LPIPS reported x100.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch
from torch import Tensor

from glimpse.metrics.image import DATA_RANGE, SSIM_K1, SSIM_K2, SSIM_SIGMA, SSIM_WIN_SIZE, psnr
from glimpse.metrics.lpips import LPIPS, LPIPS_REPORT_SCALE, LpipsNet
from glimpse.metrics.ssim_cpu import ssim_fused

TABLE_FORMAT = "glimpse-metrics/1"
PSNR_DEFINITION = (
    f"10 log10({DATA_RANGE:g}^2 / MSE), MSE over RGB of the frame (or of the masked pixels); mean over frames"
)
SSIM_DEFINITION = (
    f"scikit-image structural_similarity(gaussian_weights=True, sigma={SSIM_SIGMA}, use_sample_covariance=False, "
    f"data_range={DATA_RANGE:g}, channel_axis=-1): {SSIM_WIN_SIZE}x{SSIM_WIN_SIZE} Gaussian window, K1={SSIM_K1}, "
    f"K2={SSIM_K2}, map mean without its border strip (masked: mean of the map inside the mask); mean over frames"
)
DECIMALS = {"psnr": 2, "ssim": 4, "lpips": 2}


@dataclass(frozen=True)
class EvalProtocol:
    """How the numbers were made; written beside them.

    mask:       "none", or which mask restricted the metrics (e.g. "person masks from 03_masks").
    background: RGB in [0, 1] composited behind rendered and ground-truth foregrounds, or
                None when whole frames are compared as they are.
    frames:     which frames were scored (e.g. "held-out camera, every 5th frame of 0-295").
    lpips_net:  "alex" (what papers report) or "vgg"; LPIPS is v0.1, inputs mapped to [-1, 1].
    """

    mask: str
    background: tuple[float, float, float] | None
    frames: str
    lpips_net: LpipsNet = "alex"
    lpips_scale: float = LPIPS_REPORT_SCALE
    psnr: str = PSNR_DEFINITION
    ssim: str = SSIM_DEFINITION
    lpips: str = "v0.1 linear heads; images in [0, 1] mapped to [-1, 1]; masked: both images zeroed outside the mask"


@dataclass(frozen=True)
class FrameMetrics:
    """One frame's scores: PSNR (dB), SSIM, LPIPS raw (not yet x100)."""

    frame: str
    psnr: float
    ssim: float
    lpips: float


@dataclass(frozen=True)
class MetricsRow:
    """One table row: means over ``n_frames`` frames; ``lpips`` already scaled (x100)."""

    label: str
    psnr: float
    ssim: float
    lpips: float
    n_frames: int
    frames: list[FrameMetrics] = field(default_factory=list)


@torch.no_grad()
def frame_metrics(
    frame: str, pred: Tensor, target: Tensor, lpips_module: LPIPS, mask: Tensor | None = None
) -> FrameMetrics:
    """Score one frame. pred, target: ``[H, W, 3]`` in [0, 1]; mask: optional ``[H, W]``."""
    return frame_metrics_against(frame, [pred], target, lpips_module, mask)[0]


@torch.no_grad()
def frame_metrics_against(
    frame: str, preds: Sequence[Tensor], target: Tensor, lpips_module: LPIPS, mask: Tensor | None = None
) -> list[FrameMetrics]:
    """``frame_metrics`` of each of ``preds`` against one target in one mask; LPIPS sees the target once."""
    if mask is None:
        lpips_values = lpips_module.distances_to(preds, target)
    else:
        weights = mask.to(target.dtype).unsqueeze(-1)
        lpips_values = lpips_module.distances_to([pred * weights for pred in preds], target * weights)
    return [FrameMetrics(frame=frame, psnr=float(psnr(pred, target, mask)), ssim=float(ssim_fused(pred, target, mask)),
                         lpips=float(lpips_value)) for pred, lpips_value in zip(preds, lpips_values, strict=True)]


def _mean(values: Sequence[float]) -> float:
    return math.fsum(values) / len(values) if values else math.nan


def summarize(label: str, frames: Sequence[FrameMetrics], lpips_scale: float = LPIPS_REPORT_SCALE) -> MetricsRow:
    """Means over frames (PSNR of each frame averaged, as papers do); LPIPS times lpips_scale."""
    return MetricsRow(
        label=label,
        psnr=_mean([f.psnr for f in frames]),
        ssim=_mean([f.ssim for f in frames]),
        lpips=_mean([f.lpips for f in frames]) * lpips_scale,
        n_frames=len(frames),
        frames=list(frames),
    )


def table_json(rows: Sequence[MetricsRow], protocol: EvalProtocol) -> dict:
    """The JSON document: format, protocol, rows (with per-frame values, LPIPS raw per frame)."""
    return {"format": TABLE_FORMAT, "protocol": asdict(protocol), "rows": [asdict(row) for row in rows]}


def table_markdown(rows: Sequence[MetricsRow], protocol: EvalProtocol, title: str = "Metrics") -> str:
    """A Markdown table of the rows' means followed by the protocol."""
    scale = f"x{protocol.lpips_scale:g}"
    lines = [
        f"# {title}",
        "",
        f"| | PSNR ↑ (dB) | SSIM ↑ | LPIPS ↓ ({scale}, {protocol.lpips_net}) | frames |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    for row in rows:
        lines.append(
            f"| {row.label} | {row.psnr:.{DECIMALS['psnr']}f} | {row.ssim:.{DECIMALS['ssim']}f} "
            f"| {row.lpips:.{DECIMALS['lpips']}f} | {row.n_frames} |"
        )
    background = "none (whole frames)" if protocol.background is None else f"RGB {tuple(protocol.background)} in [0, 1]"
    lines += [
        "",
        "Protocol:",
        f"- mask: {protocol.mask}",
        f"- background: {background}",
        f"- frames: {protocol.frames}",
        f"- PSNR: {protocol.psnr}",
        f"- SSIM: {protocol.ssim}",
        f"- LPIPS: {protocol.lpips_net}, reported {scale}; {protocol.lpips}",
    ]
    return "\n".join(lines) + "\n"


def write_metrics_table(
    rows: Sequence[MetricsRow], protocol: EvalProtocol, json_path: Path, markdown_path: Path, title: str = "Metrics"
) -> None:
    """Write the table as JSON (``json_path``) and Markdown (``markdown_path``)."""
    json_path.parent.mkdir(parents=True, exist_ok=True)
    markdown_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(table_json(rows, protocol), indent=2) + "\n")
    markdown_path.write_text(table_markdown(rows, protocol, title))
