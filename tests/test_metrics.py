"""PSNR and SSIM (glimpse.metrics.image) against scikit-image, masks, gradients; the metrics table writer."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from glimpse.metrics.image import SSIM_RADIUS, SSIM_WIN_SIZE, gaussian_window_1d, psnr, ssim, ssim_map
from glimpse.metrics.table import EvalProtocol, FrameMetrics, summarize, table_markdown, write_metrics_table

skimage_metrics = pytest.importorskip("skimage.metrics")
SKIMAGE_SSIM = dict(gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1.0, channel_axis=-1)
TOL = 1e-4


def skimage_ssim(a: np.ndarray, b: np.ndarray, full: bool = False):
    return skimage_metrics.structural_similarity(a, b, full=full, **SKIMAGE_SSIM)


def natural_ish(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """Gradient + flat rectangles + a textured band + noise, in [0, 1], [H, W, 3] float64."""
    yy, xx = np.mgrid[0:height, 0:width] / max(height, width)
    image = np.stack([xx, yy, 0.5 * (xx + yy)], axis=-1)
    image[: height // 3, : width // 2] = rng.uniform(0, 1, 3)  # constant region
    image[height // 2 :, width // 3 :] *= 0.5 + 0.5 * np.sin(25 * xx[height // 2 :, width // 3 :, None])
    return np.clip(image + rng.normal(0, 0.03, image.shape), 0, 1)


def distort(rng: np.random.Generator, image: np.ndarray, kind: str) -> np.ndarray:
    if kind == "noise":
        return np.clip(image + rng.normal(0, 0.1, image.shape), 0, 1)
    if kind == "shift":
        return np.roll(image, 1, axis=1)
    if kind == "contrast":
        return 0.7 * image + 0.2
    if kind == "random":
        return rng.uniform(0, 1, image.shape)
    raise ValueError(kind)


SIZES = [(11, 11), (16, 16), (17, 23), (31, 12), (64, 48), (101, 77)]
KINDS = ["noise", "shift", "contrast", "random"]


@pytest.mark.parametrize("size", SIZES)
@pytest.mark.parametrize("kind", KINDS)
def test_ssim_matches_skimage(size: tuple[int, int], kind: str) -> None:
    rng = np.random.default_rng(100 * SIZES.index(size) + KINDS.index(kind))
    a = natural_ish(rng, *size)
    b = distort(rng, a, kind)
    expected, expected_map = skimage_ssim(a, b, full=True)
    value, full = ssim(torch.from_numpy(a), torch.from_numpy(b), return_map=True)
    assert abs(float(value) - expected) < 1e-10
    np.testing.assert_allclose(full.numpy(), expected_map, atol=1e-10)
    value32 = ssim(torch.from_numpy(a).float(), torch.from_numpy(b).float())
    assert value32.dtype == torch.float32
    assert abs(float(value32) - expected) < TOL


def test_ssim_uniform_random_and_constant_images() -> None:
    rng = np.random.default_rng(1)
    cases = [
        (rng.uniform(0, 1, (40, 40, 3)), rng.uniform(0, 1, (40, 40, 3))),
        (np.full((20, 30, 3), 0.3), np.full((20, 30, 3), 0.8)),  # flat vs flat
        (np.full((20, 30, 3), 0.5), rng.uniform(0, 1, (20, 30, 3))),  # flat vs noise
        (np.zeros((16, 16, 3)), np.ones((16, 16, 3))),
    ]
    for a, b in cases:
        value = ssim(torch.tensor(a, dtype=torch.float32), torch.tensor(b, dtype=torch.float32))
        assert abs(float(value) - skimage_ssim(a, b)) < TOL


def test_ssim_identical_images_is_one_and_batches_keep_leading_dims() -> None:
    rng = np.random.default_rng(2)
    a = torch.from_numpy(rng.uniform(0, 1, (2, 3, 20, 24, 3)))
    b = torch.from_numpy(np.clip(a.numpy() + rng.normal(0, 0.05, a.shape), 0, 1))
    torch.testing.assert_close(ssim(a, a), torch.ones(2, 3, dtype=torch.float64))
    batched = ssim(a, b)
    assert batched.shape == (2, 3)
    for i in range(2):
        for j in range(3):
            assert abs(float(batched[i, j]) - skimage_ssim(a[i, j].numpy(), b[i, j].numpy())) < 1e-10


def test_gaussian_window_is_skimage_window() -> None:
    taps = gaussian_window_1d(torch.float64).numpy()
    assert taps.shape == (SSIM_WIN_SIZE,) == (11,)
    impulse = np.zeros(SSIM_WIN_SIZE)
    impulse[SSIM_RADIUS] = 1.0
    from scipy.ndimage import gaussian_filter1d

    np.testing.assert_allclose(taps, gaussian_filter1d(impulse, 1.5, truncate=3.5), atol=1e-15)


def test_masked_ssim_is_mean_of_map_inside_mask() -> None:
    rng = np.random.default_rng(3)
    a = natural_ish(rng, 40, 36)
    b = distort(rng, a, "noise")
    _, full = skimage_ssim(a, b, full=True)
    mask = rng.uniform(size=(40, 36)) > 0.4
    value = ssim(torch.from_numpy(a), torch.from_numpy(b), mask=torch.from_numpy(mask))
    assert abs(float(value) - full[mask].mean()) < 1e-10
    # A mask of the valid region (border strip removed) gives scikit-image's mean SSIM.
    valid = np.zeros((40, 36), dtype=bool)
    valid[SSIM_RADIUS:-SSIM_RADIUS, SSIM_RADIUS:-SSIM_RADIUS] = True
    value = ssim(torch.from_numpy(a), torch.from_numpy(b), mask=torch.from_numpy(valid))
    assert abs(float(value) - skimage_ssim(a, b)) < 1e-10


def test_ssim_rejects_images_smaller_than_the_window_and_mismatched_shapes() -> None:
    with pytest.raises(ValueError, match="at least 11x11"):
        ssim(torch.rand(10, 20, 3), torch.rand(10, 20, 3))
    with pytest.raises(ValueError, match="differ"):
        ssim(torch.rand(16, 16, 3), torch.rand(16, 17, 3))
    with pytest.raises(ValueError, match="mask"):
        ssim(torch.rand(16, 16, 3), torch.rand(16, 16, 3), mask=torch.ones(16, 15))


def test_ssim_gradient_is_correct() -> None:
    rng = np.random.default_rng(4)
    a = torch.from_numpy(rng.uniform(0, 1, (12, 13, 2))).requires_grad_(True)
    b = torch.from_numpy(rng.uniform(0, 1, (12, 13, 2)))
    mask = torch.from_numpy(rng.uniform(size=(12, 13)) > 0.5)
    assert torch.autograd.gradcheck(lambda x: ssim(x, b), (a,))
    assert torch.autograd.gradcheck(lambda x: ssim(x, b, mask=mask), (a,))
    assert torch.autograd.gradcheck(lambda x: ssim_map(x, b).sum(), (a,))


def test_psnr_values_and_mask() -> None:
    target = torch.full((8, 10, 3), 0.5)
    assert abs(float(psnr(target + 0.1, target)) - 20.0) < 1e-4  # MSE 0.01
    rng = np.random.default_rng(5)
    a = rng.uniform(0, 1, (2, 24, 20, 3))
    b = np.clip(a + rng.normal(0, 0.05, a.shape), 0, 1)
    values = psnr(torch.from_numpy(a), torch.from_numpy(b))
    for i in range(2):
        expected = skimage_metrics.peak_signal_noise_ratio(b[i], a[i], data_range=1.0)
        assert abs(float(values[i]) - expected) < 1e-10
    mask = rng.uniform(size=(2, 24, 20)) > 0.5
    masked = psnr(torch.from_numpy(a), torch.from_numpy(b), mask=torch.from_numpy(mask))
    for i in range(2):
        mse = ((a[i] - b[i]) ** 2)[mask[i]].mean()
        assert abs(float(masked[i]) - 10 * math.log10(1 / mse)) < 1e-10
    # Differences only outside the mask do not count; identical images give a finite PSNR.
    c = a.copy()
    c[~mask] = 0.0
    assert float(psnr(torch.from_numpy(c), torch.from_numpy(a), torch.from_numpy(mask))[0]) == pytest.approx(100.0)


def test_metrics_table_json_and_markdown(tmp_path) -> None:
    protocol = EvalProtocol(mask="person masks (03_masks)", background=(1.0, 1.0, 1.0), frames="every 10th frame of 0-90")
    frames = [FrameMetrics("000000", 30.0, 0.95, 0.05), FrameMetrics("000010", 32.0, 0.97, 0.07)]
    row = summarize("ours", frames)
    assert (row.psnr, row.ssim, row.n_frames) == (31.0, 0.96, 2)
    assert row.lpips == pytest.approx(6.0)  # x100
    write_metrics_table([row], protocol, tmp_path / "m.json", tmp_path / "md" / "m.md")
    doc = json.loads((tmp_path / "m.json").read_text())
    assert doc["format"] == "glimpse-metrics/1"
    assert doc["protocol"]["lpips_net"] == "alex" and doc["protocol"]["lpips_scale"] == 100.0
    assert doc["protocol"]["background"] == [1.0, 1.0, 1.0]
    assert doc["rows"][0]["frames"][1]["lpips"] == 0.07
    markdown = (tmp_path / "md" / "m.md").read_text()
    assert markdown == table_markdown([row], protocol)
    assert "| ours | 31.00 | 0.9600 | 6.00 | 2 |" in markdown
    for needle in ("mask: person masks", "background: RGB (1.0, 1.0, 1.0)", "every 10th frame", "x100, alex", "sigma=1.5"):
        assert needle in markdown
