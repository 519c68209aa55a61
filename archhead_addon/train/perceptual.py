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

import copy
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


class _FoldedFirstSlice(nn.Sequential):
    """The trunk's first slice, (11x11 convolution, blur-subsample, ReLU), with the two linear
    layers folded into one: the blur of the convolution is a 13x13 convolution of stride 2,
    which on the image's four pixel phases (`pixel_unshuffle`) is a 7x7 convolution of
    stride 1 over 12 channels, at a quarter of the pixels. 2.2x faster forward and backward
    than convolving at full resolution and then blurring, and the same up to float32
    round-off: the outermost row and column on each side, where the blur reflects the
    convolution's output, are computed the plain way from thin strips of the image. Images
    of an odd size take the plain way."""

    def forward(self, x):
        conv, blur, relu = self
        if conv.weight.requires_grad or x.shape[-1] % 2 or x.shape[-2] % 2:
            return relu(blur(conv(x)))
        w, b, f = conv.weight, conv.bias, blur.filt[:1]
        out_c, in_c, k, _ = w.shape  # k = 11, padding 2: the output is 6 px smaller
        c = F.conv2d(F.pad(w.reshape(-1, 1, k, k), (2, 2, 2, 2)), f)  # the 13x13 kernels
        c = F.pad(c, (0, 1, 0, 1)).reshape(out_c, in_c, 7, 2, 7, 2)  # tap 2u + r -> (u, r)
        phases = c.permute(0, 1, 3, 5, 2, 4).reshape(out_c, 4 * in_c, 7, 7)
        z = _WideConvFunction.apply(F.pixel_unshuffle(x, 2), phases, b, (2, 2))
        padded = F.pad(x, (2, 2, 2, 2))
        across = padded.transpose(2, 3)
        rows, cols = z.shape[2:]
        top, bottom = (_exact_rows(padded, w, b, f, r) for r in (0, rows - 1))
        left, right = (
            _exact_rows(across, w.transpose(2, 3), b, f, r).transpose(2, 3) for r in (0, cols - 1)
        )
        middle = torch.cat([left[:, :, 1:-1], z[:, :, 1:-1, 1:-1], right[:, :, 1:-1]], dim=3)
        return relu(torch.cat([top, middle, bottom], dim=2))


def _exact_rows(padded, w, b, f, row: int):
    """Row `row` of blur-subsample(conv(x)) the plain way, from the rows of the zero-padded
    image (by 2, the convolution's padding) that it needs: the blur reflects at the edges."""
    height = padded.shape[2] - w.shape[2] + 1  # the convolution's output rows

    def reflect(j: int) -> int:
        return -j if j < 0 else 2 * (height - 1) - j if j >= height else j

    wanted = [reflect(j - 2) for j in range(2 * row, 2 * row + 3)]
    lo, hi = min(wanted), max(wanted)
    y = _WideConvFunction.apply(padded[:, :, lo : hi + w.shape[2]], w, b, (0, 0))
    y = y.index_select(2, torch.tensor([i - lo for i in wanted], device=y.device))
    y = F.pad(y, (2, 2, 0, 0), mode="reflect")
    return F.conv2d(y, f.expand(y.shape[1], -1, -1, -1), stride=2, groups=y.shape[1])


def _slice(layers: dict[int, nn.Module], kind=nn.Sequential) -> nn.Sequential:
    """A Sequential whose children keep the trunk's layer indices (the weights' key names)."""
    seq = kind()
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
                _slice(
                    {0: _FrozenWideConv(3, 64, 11, padding=2), 1: _BlurDown(64), 2: relu()},
                    _FoldedFirstSlice,
                ),
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


def unfolded(lpips: ShiftTolerantLPIPS) -> ShiftTolerantLPIPS:
    """A copy whose first slice is torch's own convolution, blur and ReLU one after another,
    with torch's backward: what the folded slice is held to (tests, benchmarks)."""
    plain = copy.deepcopy(lpips)
    first = plain.trunk[0]
    conv = nn.Conv2d(3, 64, 11, padding=2).requires_grad_(False)
    conv.load_state_dict(first[0].state_dict())
    plain.trunk[0] = nn.Sequential(conv, first[1], first[2])
    return plain


def _unit(feat: torch.Tensor, eps: float = 1e-10) -> torch.Tensor:
    """Each pixel's feature vector divided by its length (LPIPS's normalisation)."""
    return feat / (feat.square().sum(dim=1, keepdim=True).sqrt() + eps)
