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
"""

from __future__ import annotations

from collections.abc import Mapping

import torch

from .bicubic import resize_matrix
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
    """(N, C): the blended field at `texel` (N,), distinct flat indices row * S + col."""
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
