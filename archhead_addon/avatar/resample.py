"""The feature field at the texels of one resolution S, in torch (paper eq. 4-5): every level
F_i (C, s_i, s_i) resized bicubically to S, blended, sum_i w_i A_i F_i A_i^T, and read at the
texels the UV layout covers.

The resize is two matrix products with the 1-D matrices of `bicubic.resize_matrix`, the
numbers of F.interpolate(mode="bicubic", align_corners=False, antialias=False), which the
tests hold it to. On a CPU, F.interpolate's bicubic backward scatters tap by tap; with these
products and the row read below, a training step's resample took 2.5-4.4x less time
(docs/training_profile.md). A level already at S is not resized at all.

The blend is built texel-major, (S * S, C), so that reading the texels copies whole rows,
and the read's backward writes each row once (the texels are distinct) instead of
accumulating, column by column, into a channel-major map: several times cheaper.

On a CPU (float32 levels) the splat kernel's library does it instead, by the four taps of
each output (`kernel.resample_forward`, csrc/resample.hpp): the dense products spend all
but 4 of every s multiplications on zeros; the kernel's is 1.9-2.9 times faster forward and
backward, a training step 1.11-1.13 times (benchmarks/kernel_ops.py). The products stay for
other devices, and as the reference the tests hold the kernel's to.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping

import numpy as np
import torch

from ..splat import kernel
from ..splat.autograd import cpu_float32
from .bicubic import resize_matrix, taps
from .lod import blend_weights

Plan = tuple[tuple[str, float, torch.Tensor | None], ...]


def resample_plan(levels, size: int, tau: float, device) -> Plan:
    """(level key, blend weight, bicubic matrix (size, s), None for s == size) per level."""
    return tuple(
        (
            str(s),
            float(w),
            None if s == size else torch.from_numpy(resize_matrix(s, size)).to(device),
        )
        for w, s in zip(blend_weights(levels, size, tau), levels, strict=True)
    )


def texel_features(features: Mapping[str, torch.Tensor], plan: Plan, texel) -> torch.Tensor:
    """(N, C): the blended field at `texel` (N,), distinct flat indices row * S + col: by the
    splat kernel for float32 CPU levels, else `texel_features_torch`."""
    levels = [features[key] for key, _, _ in plan]
    if cpu_float32(*levels):
        size = levels[0].shape[1] if plan[0][2] is None else plan[0][2].shape[0]
        steps = tuple((float(weight), size) for _, weight, _ in plan)
        return _ResampleCPU.apply(steps, texel, *levels)
    return texel_features_torch(features, plan, texel)


def texel_features_torch(features: Mapping[str, torch.Tensor], plan: Plan, texel):
    """`texel_features` by the dense matrix products (module docstring)."""
    grid = None  # (S, S * C): row, then column and channel
    for key, weight, a in plan:
        f = features[key]
        c, s = f.shape[0], f.shape[1]
        if a is None:
            grid_i = weight * f.permute(1, 2, 0).reshape(s, s * c)
        else:
            a = a.to(f.dtype)
            size = a.shape[0]
            cols = (f.reshape(c * s, s) @ a.T).reshape(c, s, size)  # (C, s, S)
            cols = cols.permute(1, 2, 0).reshape(s, size * c)
            grid_i = (weight * a) @ cols
        grid = grid_i if grid is None else grid + grid_i
    return _GatherRows.apply(grid.reshape(-1, c), texel)


class _GatherRows(torch.autograd.Function):
    """src[index] for distinct indices; the backward copies rows back (nothing to add)."""

    @staticmethod
    def forward(ctx, src, index):
        ctx.save_for_backward(index)
        ctx.rows = src.shape[0]
        return src.index_select(0, index)

    @staticmethod
    def backward(ctx, grad):
        (index,) = ctx.saved_tensors
        out = grad.new_zeros(ctx.rows, grad.shape[1])
        return out.index_copy_(0, index, grad), None


@functools.lru_cache(maxsize=1024)
def _taps(s: int, size: int):
    """bicubic.taps(s, size) as the kernel reads them: (int32 index, float32 weight)."""
    index, weight = taps(s, size)
    return np.ascontiguousarray(index, np.int32), np.ascontiguousarray(weight, np.float32)


class _ResampleCPU(torch.autograd.Function):
    """The field at the texels by the splat kernel, level by level (kernel.resample_forward).
    `steps`: (blend weight, S) per level, in the order of the level tensors. It runs on
    torch's threads (splat.autograd.cpu_float32)."""

    @staticmethod
    def forward(ctx, steps, texel, *levels):
        index = texel.detach().to(torch.int64).contiguous().numpy()
        threads = torch.get_num_threads()
        out = np.zeros((len(index), levels[0].shape[0]), np.float32)
        for (weight, size), f in zip(steps, levels, strict=True):
            s = f.shape[1]
            level_taps = None if s == size else _taps(s, size)
            host = f.detach().contiguous().numpy()
            kernel.resample_forward(host, size, level_taps, weight, index, out, threads)
        ctx.steps, ctx.index, ctx.threads = steps, index, threads
        ctx.shapes = [tuple(f.shape) for f in levels]
        return torch.from_numpy(out)

    @staticmethod
    def backward(ctx, grad):
        g = grad.detach().contiguous().numpy()
        grads = []
        for (weight, size), shape, needed in zip(
            ctx.steps, ctx.shapes, ctx.needs_input_grad[2:], strict=True
        ):
            if not needed:  # a level frozen this stage (stage 4 trains the sparsest alone)
                grads.append(None)
                continue
            level_taps = None if shape[1] == size else _taps(shape[1], size)
            grad_f = kernel.resample_backward(
                shape, size, level_taps, weight, ctx.index, g, ctx.threads
            )
            grads.append(torch.from_numpy(grad_f))
        return (None, None, *grads)
