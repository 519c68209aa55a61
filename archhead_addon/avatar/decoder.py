"""The decoder: five MLP heads on each texel's vector, their first layers fused into one.

Its forward and backward run texels in chunks (`CHUNK`), as the numpy runtime's decode does:
each chunk's activations stay in cache from one layer to the next, where whole-frame layers
sent every activation through memory between products, and a ReLU or its gradient cost as
much as a product on the training machine's memory. The chunked backward also leaves out
what autograd's would build: the gradient of the fused activation assembled from the heads'
parts, and the bias copies of its products. The numbers are the whole-frame network's up to
float32 round-off (the weights' gradients are sums over chunks).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from .config import AvatarConfig

CHUNK = 3072  # texels per pass on a CPU: the fused activation (3072 x 192 floats) is 2.4 MB


class _Head(nn.Module):
    def __init__(self, width: int, n_hidden: int, out: int):
        super().__init__()
        self.hidden = nn.ModuleList(nn.Linear(width, width) for _ in range(n_hidden))
        self.out = nn.Linear(width, out)

    def layers(self) -> list[nn.Linear]:
        return [*self.hidden, self.out]


class Decoder(nn.Module):
    """Five MLP heads on the per-texel vector; their first layers fused into one."""

    def __init__(self, config: AvatarConfig):
        super().__init__()
        self.slices = config.head_slices()
        self.first = nn.Linear(config.in_dim, config.fused_width)
        self.heads = nn.ModuleDict(
            {
                name: _Head(config.head_width(name), config.head_layers - 1, width)
                for name, width in config.head_outputs().items()
            }
        )

    def forward(self, texel: list[torch.Tensor], frame: torch.Tensor) -> dict[str, torch.Tensor]:
        """Raw head outputs from the per-texel inputs, blocks of columns (N, PE), (N, feature),
        and the frame's, (drive | l), which every texel shares: they enter the first layer as
        part of its bias rather than as N copies of an input (the numpy runtime's form, too).
        A block that needs no gradient (the PE, unless the run refines the codes) gets none."""
        w = self.first.weight
        bias = torch.addmv(self.first.bias, w[:, sum(x.shape[1] for x in texel) :], frame)
        layers = [head.layers() for head in self.heads.values()]
        params = [p for head in layers for layer in head for p in (layer.weight, layer.bias)]
        chunk = CHUNK if w.device.type == "cpu" else len(texel[0])
        plan = (chunk, len(texel), tuple(self.slices.values()), tuple(map(len, layers)))
        outputs = _ChunkedNetwork.apply(plan, bias, w, *texel, *params)
        return dict(zip(self.heads, outputs, strict=True))


class _ChunkedNetwork(torch.autograd.Function):
    """The network from the first layer's per-frame bias on; inputs: plan, bias (fused,),
    the first layer's weight (fused, in_dim), the texel blocks, then each head's layers'
    (weight, bias) in order. plan: (chunk, number of blocks, each head's rows in the fused
    activation, each head's layer count)."""

    @staticmethod
    def forward(ctx, plan, bias, w_first, *rest):
        chunk, n_blocks, rows, depths = plan
        blocks, params = rest[:n_blocks], rest[n_blocks:]
        heads = _split(params, depths)
        n = len(blocks[0])
        fused = blocks[0].new_empty(n, len(bias))
        # each head's layers' outputs; the hidden ones (after their ReLU) are kept for backward
        acts = [[fused.new_empty(n, layer[0].shape[0]) for layer in head] for head in heads]
        for c in _chunks(n, chunk):
            h = fused[c]
            for i, (x, cols) in enumerate(zip(blocks, _columns(blocks), strict=True)):
                if i == 0:
                    torch.addmm(bias, x[c], w_first[:, cols].t(), out=h)
                else:
                    h.addmm_(x[c], w_first[:, cols].t())
            h.relu_()
            for head, out, r in zip(heads, acts, rows, strict=True):
                x = h[:, r]
                for j, (weight, b) in enumerate(head):
                    x = torch.addmm(b, x, weight.t(), out=out[j][c])
                    if j < len(head) - 1:
                        x.relu_()
        ctx.plan = plan
        ctx.save_for_backward(w_first, fused, *blocks, *params, *(a for out in acts for a in out))
        return tuple(out[-1] for out in acts)

    @staticmethod
    def backward(ctx, *grads):
        chunk, n_blocks, rows, depths = ctx.plan
        saved = ctx.saved_tensors
        w_first, fused, blocks = saved[0], saved[1], saved[2 : 2 + n_blocks]
        params = saved[2 + n_blocks : 2 + n_blocks + 2 * sum(depths)]
        acts = _split_rows(saved[2 + n_blocks + len(params) :], depths)
        heads = _split(params, depths)
        needs = ctx.needs_input_grad
        need_bias, need_w = needs[1], needs[2]
        need_blocks = needs[3 : 3 + n_blocks]
        need_params = needs[3 + n_blocks :]
        g_params = [
            torch.zeros_like(p) if need else None
            for p, need in zip(params, need_params, strict=True)
        ]
        g_heads = _split(g_params, depths)
        g_bias = torch.zeros_like(fused[0]) if need_bias else None
        g_w = torch.zeros_like(w_first) if need_w else None
        g_blocks = [
            torch.empty_like(x) if need else None
            for x, need in zip(blocks, need_blocks, strict=True)
        ]
        n = len(fused)
        g_fused = fused.new_empty(min(chunk, n), fused.shape[1])
        for c in _chunks(n, chunk):
            h, g_h = fused[c], g_fused[: c.stop - c.start]
            for head, g_head, out, grad, r in zip(heads, g_heads, acts, grads, rows, strict=True):
                g = grad[c]
                for j in range(len(head) - 1, -1, -1):
                    x = out[j - 1][c] if j else h[:, r]
                    (weight, _), (g_weight, g_b) = head[j], g_head[j]
                    if g_weight is not None:
                        g_weight.addmm_(g.t(), x)
                    if g_b is not None:
                        g_b.add_(g.sum(0))
                    if j:
                        g = torch.mm(g, weight).mul_(x > 0)
                    else:
                        torch.mm(g, weight, out=g_h[:, r])
            g_h.mul_(h > 0)
            if g_bias is not None:
                g_bias.add_(g_h.sum(0))
            for x, g_x, cols in zip(blocks, g_blocks, _columns(blocks), strict=True):
                if g_w is not None:
                    g_w[:, cols].addmm_(g_h.t(), x[c])
                if g_x is not None:
                    torch.mm(g_h, w_first[:, cols], out=g_x[c])
        return (None, g_bias, g_w, *g_blocks, *g_params)


def _split(flat, depths) -> list[list[tuple]]:
    """Flat (weight, bias, weight, bias, ...) into each head's list of (weight, bias)."""
    heads, k = [], 0
    for depth in depths:
        heads.append([(flat[k + 2 * j], flat[k + 2 * j + 1]) for j in range(depth)])
        k += 2 * depth
    return heads


def _split_rows(flat, depths) -> list[list]:
    heads, k = [], 0
    for depth in depths:
        heads.append(list(flat[k : k + depth]))
        k += depth
    return heads


def _columns(blocks) -> list[slice]:
    """Each texel block's columns in the first layer's weight."""
    out, k = [], 0
    for x in blocks:
        out.append(slice(k, k + x.shape[1]))
        k += x.shape[1]
    return out


def _chunks(n: int, chunk: int) -> list[slice]:
    return [slice(start, min(n, start + chunk)) for start in range(0, n, chunk)]


def plain_forward(decoder: Decoder, texel: list[torch.Tensor], frame: torch.Tensor) -> dict:
    """The same network as whole-frame torch layers under autograd (the decoder's form until
    2026-11-30): the reference the chunked form is tested and timed against. One product per
    texel block, so autograd skips the input gradient of a block that needs none."""
    w, k = decoder.first.weight, 0
    h = torch.addmv(decoder.first.bias, w[:, sum(x.shape[1] for x in texel) :], frame)
    for block in texel:
        h = F.linear(block, w[:, k : k + block.shape[1]], h)
        k += block.shape[1]
    widths = [part.stop - part.start for part in decoder.slices.values()]
    h = dict(zip(decoder.slices, F.relu(h).split(widths, dim=1), strict=True))
    out = {}
    for name, head in decoder.heads.items():
        x = h[name]
        for layer in head.hidden:
            x = F.relu(layer(x))
        out[name] = head.out(x)
    return out
