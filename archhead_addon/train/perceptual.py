"""The perceptual term and metric: shift-tolerant LPIPS (ST-LPIPS; Ghildyal and Liu, ECCV 2022)
with its AlexNet trunk.

LPIPS compares the channel-normalised activations of five layers of a trained network, weighted
per channel by learned linear layers (Zhang et al., CVPR 2018). ST-LPIPS retrains it with
anti-aliased pooling (blur before every subsampling, reflection padding, a stride-1 first
convolution), so a one-pixel shift of an image barely changes the distance. Its weights ship
inside the `stlpips-pytorch` wheel (trunk and linear layers in one state dict, ~10 MB), so
the metric loads offline. The package's own code imports torchvision, IPython and torchsummary
(undeclared), so the network is rebuilt here with the same layer names and the weights file is
loaded strictly with `torch.load(weights_only=True)`; `tests/test_losses.py` holds it to
distances computed with the package's own implementation.

Values are not comparable with the original LPIPS (the paper's metric): same idea, another
network.
"""

from __future__ import annotations

import importlib.resources
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

WEIGHTS = ("stlpips_pytorch", "weights/vST0.0/alex_shift_tolerant.pth")
CHANNELS = (64, 192, 384, 256, 256)


class Reference(NamedTuple):
    """A reference image's features for `ShiftTolerantLPIPS.compare`."""

    shape: tuple[int, ...]
    features: list[torch.Tensor]


class _BlurDown(nn.Module):
    """Reflection-pad by 2, blur with the 3x3 binomial filter, keep every second pixel."""

    def __init__(self, channels: int):
        super().__init__()
        a = torch.tensor([1.0, 2.0, 1.0])
        filt = (a[:, None] * a[None, :]) / 16.0
        self.register_buffer("filt", filt[None, None].repeat(channels, 1, 1, 1))

    def forward(self, x):
        return F.conv2d(
            F.pad(x, (2, 2, 2, 2), mode="reflect"), self.filt, stride=2, groups=x.shape[1]
        )


class _FrozenWideConv(nn.Conv2d):
    """A stride-1 convolution with frozen weights and a wide kernel (the trunk's first,
    11x11 from 3 channels), whose input gradient is computed row by row: the transposed
    convolution's taps of each kernel column become output channels of one (kh, 1)
    convolution, then shifted and summed. On a CPU that is 3x faster than the library's
    backward, which runs at a fifth of the forward's rate with 3 output channels."""

    def forward(self, x):
        if self.weight.requires_grad or self.stride != (1, 1) or self.dilation != (1, 1):
            return super().forward(x)
        return _WideConvFunction.apply(x, self.weight, self.bias, self.padding)


class _WideConvFunction(torch.autograd.Function):
    @staticmethod
    def forward(ctx, x, weight, bias, padding):
        ctx.save_for_backward(weight)
        ctx.padding, ctx.width = padding, x.shape[-1]
        return F.conv2d(x, weight, bias, padding=padding)

    @staticmethod
    def backward(ctx, grad):
        (weight,) = ctx.saved_tensors
        (ph, pw), width = ctx.padding, ctx.width
        out_c, in_c, kh, kw = weight.shape
        # The transposed convolution's kernel, (in_c, out_c, kh, kw), its columns as channels.
        flipped = weight.flip(2, 3).transpose(0, 1)
        rows = flipped.permute(0, 3, 1, 2).reshape(in_c * kw, out_c, kh, 1)
        u = F.conv2d(grad, rows.to(grad.dtype), padding=(kh - 1 - ph, 0))
        u = F.pad(u.unflatten(1, (in_c, kw)), (kw - 1 - pw, kw - 1 - pw))
        dx = u[:, :, 0, :, 0:width].clone()
        for j in range(1, kw):
            dx += u[:, :, j, :, j : j + width]
        return dx, None, None, None


def _slice(layers: dict[int, nn.Module]) -> nn.Sequential:
    """A Sequential whose children keep the trunk's layer indices (the weights' key names)."""
    seq = nn.Sequential()
    for index, layer in layers.items():
        seq.add_module(str(index), layer)
    return seq


class ShiftTolerantLPIPS(nn.Module):
    """Distance between images (N,3,H,W) in [0, 1]; returns (N,). Frozen, eval mode.

    Images need at least 32 pixels a side (the trunk subsamples three times)."""

    def __init__(self):
        super().__init__()
        self.register_buffer("shift", torch.zeros(1, 3, 1, 1))
        self.register_buffer("scale", torch.ones(1, 3, 1, 1))
        relu, pool = nn.ReLU, nn.MaxPool2d
        self.trunk = nn.ModuleList(
            [
                _slice({0: _FrozenWideConv(3, 64, 11, padding=2), 1: _BlurDown(64), 2: relu()}),
                _slice(
                    {
                        3: pool(3, stride=1),
                        4: _BlurDown(64),
                        5: nn.Conv2d(64, 192, 5, padding=2),
                        6: relu(),
                    }
                ),
                _slice(
                    {
                        7: pool(3, stride=1),
                        8: _BlurDown(192),
                        9: nn.Conv2d(192, 384, 3, padding=1),
                        10: relu(),
                    }
                ),
                _slice({11: nn.Conv2d(384, 256, 3, padding=1), 12: relu()}),
                _slice({13: nn.Conv2d(256, 256, 3, padding=1), 14: relu()}),
            ]
        )
        self.lins = nn.ModuleList(nn.Conv2d(c, 1, 1, bias=False) for c in CHANNELS)
        self._load()
        self.requires_grad_(False)
        self.eval()

    def _load(self) -> None:
        path = importlib.resources.files(WEIGHTS[0]).joinpath(WEIGHTS[1])
        with importlib.resources.as_file(path) as file:
            stored = torch.load(file, map_location="cpu", weights_only=True)
        renamed = {}
        for key, value in stored.items():
            if key.startswith("scaling_layer."):
                key = key.removeprefix("scaling_layer.")
            elif key.startswith("net.slice"):
                k, rest = key.removeprefix("net.slice").split(".", 1)
                key = f"trunk.{int(k) - 1}.{rest}"
            elif key.startswith("lin"):
                key = f"lins.{key[3]}.weight"  # lin<k>.model.1.weight (after a dropout)
            renamed[key] = value
        self.load_state_dict(renamed, strict=True)

    def forward(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        if a.shape != b.shape or a.ndim != 4 or a.shape[1] != 3:
            raise ValueError(
                f"expected two (N,3,H,W) images, got {tuple(a.shape)} and {tuple(b.shape)}"
            )
        return self.compare(a, self.reference(b))

    def reference(self, b: torch.Tensor) -> Reference:
        """The unit-length features of images b (N,3,H,W), without a graph unless b needs one:
        what `compare` measures against (a training step's renders share their frame's)."""
        if b.ndim != 4 or b.shape[1] != 3:
            raise ValueError(f"expected (N,3,H,W) images, got {tuple(b.shape)}")
        if min(b.shape[2:]) < 32:
            raise ValueError(f"ST-LPIPS needs images of at least 32x32 px, got {tuple(b.shape)}")
        with torch.set_grad_enabled(torch.is_grad_enabled() and b.requires_grad):
            return Reference(tuple(b.shape), self._features(b))

    def compare(self, a: torch.Tensor, reference: Reference) -> torch.Tensor:
        """Distances (N,) of images a (N,3,H,W) from a `reference` of images of their shape."""
        if tuple(a.shape) != reference.shape:
            raise ValueError(
                f"expected two (N,3,H,W) images, got {tuple(a.shape)} and {reference.shape}"
            )
        total = a.new_zeros(len(a))
        for x, y, lin in zip(self._features(a), reference.features, self.lins, strict=True):
            total = total + lin((x - y) ** 2).mean(dim=(1, 2, 3))
        return total

    def _features(self, images: torch.Tensor) -> list[torch.Tensor]:
        # Channels-last: the library's CPU convolutions and max pooling run 1.5x faster so. A
        # copy, since a permuted (H,W,3) image passes as channels-last yet is not taken so.
        x = (((2 * images - 1) - self.shift) / self.scale).clone(memory_format=torch.channels_last)
        feats = []
        for layer in self.trunk:
            x = layer(x)
            feats.append(_unit(x))
        return feats


def _unit(feat: torch.Tensor, eps: float = 1e-10) -> torch.Tensor:
    """Each pixel's feature vector divided by its length (LPIPS's normalisation)."""
    return feat / (feat.square().sum(dim=1, keepdim=True).sqrt() + eps)
