"""torch.autograd.Function around the CPU kernel (training on machines without CUDA)."""

from __future__ import annotations

import torch
from torch.autograd.function import once_differentiable

from . import kernel


class SplatCPU(torch.autograd.Function):
    """(means, quats, log_scales, opacity_logits, colors) -> (rgb, alpha, depth_acc).

    Computes in float32 on the CPU (inputs on other devices or dtypes are converted and the
    gradients converted back); outputs are float32 on the inputs' device. depth_acc is the
    accumulated sum_i w_i z_i. Double backward is not supported.
    """

    @staticmethod
    def forward(ctx, means, quats, log_scales, opacity_logits, colors, settings):
        inputs = (means, quats, log_scales, opacity_logits, colors)
        gaussians = kernel.Gaussians.checked(*(t.detach().cpu().numpy() for t in inputs))
        raster, handle = kernel.forward(gaussians, settings)
        ctx.handle = handle
        ctx.like = [(t.dtype, t.device) for t in inputs]
        ctx.set_materialize_grads(False)
        return tuple(torch.from_numpy(a).to(means.device) for a in raster)

    @staticmethod
    @once_differentiable
    def backward(ctx, g_rgb, g_alpha, g_depth):
        def host(g):
            return None if g is None else g.detach().cpu().numpy()

        if g_rgb is None:
            g_rgb = torch.zeros(ctx.handle.shape + (3,))
        grads = kernel.backward(ctx.handle, host(g_rgb), host(g_alpha), host(g_depth))
        out = [
            torch.from_numpy(g).to(dtype=dtype, device=device)
            for g, (dtype, device) in zip(grads, ctx.like, strict=True)
        ]
        return (*out, None)


def splat_cpu(means, quats, log_scales, opacity_logits, colors, settings: kernel.RasterSettings):
    """Differentiable CPU render: (rgb (H,W,3), alpha (H,W), depth_acc (H,W))."""
    return SplatCPU.apply(means, quats, log_scales, opacity_logits, colors, settings)
