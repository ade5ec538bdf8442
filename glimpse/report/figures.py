"""The report's pictures: plots of what the stages logged (matplotlib, no pyplot state) and stills taken from
the run's frames, masks and videos. Each function returns an image array or writes one PNG; none reads JSON."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from PIL import Image

from glimpse.io.video import iter_video_frames, probe_video
from glimpse.report.config import ReportConfig

# One colour per person, the same in every plot and mask still (matplotlib's tab10, as RGB 0..255).
PERSON_COLOURS = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75),
                  (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207)]


def person_colour(index: int) -> tuple[int, int, int]:
    return PERSON_COLOURS[index % len(PERSON_COLOURS)]


Series = tuple[str, Sequence[float], Sequence[float]]  # (label, x values, y values)


def line_plot(path: Path, config: ReportConfig, title: str, xlabel: str, ylabel: str, series: list[Series],
              log_y: bool = False, markers: bool = False) -> None:
    """One PNG with a line per series (legend when several)."""
    figure = Figure(figsize=(config.figure_width_in, config.figure_width_in / 2), layout="constrained")
    axes = figure.add_subplot()
    for label, xs, ys in series:
        axes.plot(xs, ys, label=label, marker="o" if markers else None, markersize=3, linewidth=1.2)
    axes.set(title=title, xlabel=xlabel, ylabel=ylabel)
    if log_y:
        axes.set_yscale("log")
    axes.grid(True, alpha=0.3)
    if len(series) > 1:
        figure.legend(loc="outside right upper", fontsize="small")
    figure.savefig(path, dpi=config.figure_dpi, metadata={"Software": None})


def bar_plot(path: Path, config: ReportConfig, title: str, ylabel: str, labels: list[str],
             stacks: dict[str, list[float]]) -> None:
    """Stacked horizontal bars: one bar per label, one segment per key of ``stacks`` (values per label)."""
    figure = Figure(figsize=(config.figure_width_in, max(2.0, 0.35 * len(labels) + 1.0)), layout="constrained")
    axes = figure.add_subplot()
    left = np.zeros(len(labels))
    for name, values in stacks.items():
        axes.barh(labels, values, left=left, label=name)
        left += np.asarray(values, float)
    axes.invert_yaxis()
    axes.set(title=title, xlabel=ylabel)
    axes.grid(True, axis="x", alpha=0.3)
    if len(stacks) > 1:
        figure.legend(loc="outside right upper", fontsize="small")
    figure.savefig(path, dpi=config.figure_dpi, metadata={"Software": None})


def spread_indices(count: int, wanted: int) -> list[int]:
    """``wanted`` indices evenly spread over range(count) (all of them when there are fewer), first and last
    included."""
    if count <= 0:
        return []
    if count <= wanted:
        return list(range(count))
    return sorted({int(round(i)) for i in np.linspace(0, count - 1, wanted)})


def scaled_to_height(rgb: np.ndarray, height: int) -> np.ndarray:
    """[H, W, 3] uint8 scaled to ``height`` rows, keeping the aspect ratio; enlarged with the nearest pixel (so
    a 96-row input stays sharp), reduced with area filtering."""
    h, w = rgb.shape[:2]
    if h == height:
        return rgb
    width = max(1, round(w * height / h))
    method = Image.Resampling.NEAREST if height > h else Image.Resampling.BOX
    return np.asarray(Image.fromarray(rgb).resize((width, height), method))


def mask_overlay(frame: np.ndarray, masks: Sequence[np.ndarray | None], opacity: float) -> np.ndarray:
    """[H, W, 3] uint8: ``frame`` with the i-th mask ([H, W] bool, or None) coloured in person_colour(i)."""
    out = frame.astype(np.float32)
    for index, mask in enumerate(masks):
        if mask is None:
            continue
        colour = np.asarray(person_colour(index), np.float32)
        out[mask] = (1.0 - opacity) * out[mask] + opacity * colour
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def video_stills(path: Path, wanted: int) -> list[tuple[int, np.ndarray]]:
    """(frame index, [H, W, 3] uint8) of ``wanted`` frames evenly spread over the video, decoding only up to
    the last of them."""
    count = probe_video(path).frame_count
    indices = spread_indices(count, wanted)
    if not indices:
        return []
    return list(iter_video_frames(path, set(indices), f"report stills {path.name}"))
