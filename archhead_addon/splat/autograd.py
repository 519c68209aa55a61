"""torch.autograd.Functions around the CPU kernel (training on machines without CUDA): the
splat, the sRGB encoding of its image and the loss's two image terms."""

from __future__ import annotations

import torch
from torch.autograd.function import once_differentiable

from . import kernel
from .frame import FIELDS, SplatFrame


class SplatCPU(torch.autograd.Function):
    """(settings, the frame's tensors in field order) -> (rgb, alpha, depth_acc); autograd
    takes tensors only as positional arguments, so `splat_cpu` spreads a frame here and
    both directions pair them with the field names again.

    Computes in float32 on the CPU (inputs on other devices or dtypes are converted and the
    gradients converted back); outputs are float32 on the inputs' device. depth_acc is the
    accumulated sum_i w_i z_i. Double backward is not supported.
    """

    @staticmethod
    def forward(ctx, settings, *tensors):
        host = {name: t.detach().cpu().numpy() for name, t in zip(FIELDS, tensors, strict=True)}
        raster, handle = kernel.forward(SplatFrame(**host).checked(), settings)
        ctx.handle = handle
        ctx.like = [(t.dtype, t.device) for t in tensors]
        ctx.set_materialize_grads(False)
        return tuple(torch.from_numpy(a).to(tensors[0].device) for a in raster)

    @staticmethod
    @once_differentiable
    def backward(ctx, g_rgb, g_alpha, g_depth):
        def host(g):
            return None if g is None else g.detach().cpu().numpy()

        if g_rgb is None:
            g_rgb = torch.zeros(ctx.handle.shape + (3,))
        grads = kernel.backward(ctx.handle, host(g_rgb), host(g_alpha), host(g_depth)).arrays()
        out = [
            torch.from_numpy(grads[name]).to(dtype=dtype, device=device)
            for name, (dtype, device) in zip(FIELDS, ctx.like, strict=True)
        ]
        return (None, *out)


def splat_cpu(frame: SplatFrame, settings: kernel.RasterSettings):
    """Differentiable CPU render of a frame of tensors (RGB in sh): (rgb (H,W,3), alpha
    (H,W), depth_acc (H,W))."""
    return SplatCPU.apply(settings, *(getattr(frame, name) for name in FIELDS))


def cpu_float32(*tensors) -> bool:
    """Whether the kernel's one-pass operations below (and avatar/resample.py's) take these
    tensors: float32 on the CPU. Others go through the torch operations they replace. The
    operations run on torch's threads (`torch.set_num_threads`, which training sets from its
    config), as those would."""
    return all(t.device.type == "cpu" and t.dtype == torch.float32 for t in tensors)


class SrgbEncodeCPU(torch.autograd.Function):
    """colour_space.linear_to_srgb of a float32 CPU tensor by the kernel, which gives the
    derivative with the values: the backward is one product."""

    @staticmethod
    def forward(ctx, x):
        y, slope = kernel.srgb_encode(x.detach().numpy(), torch.get_num_threads())
        ctx.save_for_backward(torch.from_numpy(slope))
        return torch.from_numpy(y)

    @staticmethod
    @once_differentiable
    def backward(ctx, grad):
        (slope,) = ctx.saved_tensors
        return grad * slope


class ImageHuberCPU(torch.autograd.Function):
    """(Huber(pred, target), Huber(pred B, target B)) of float32 CPU images by the kernel
    (kernel.image_huber), which gives the gradients with the values. target and parts
    take no gradient."""

    @staticmethod
    def forward(ctx, pred, target, parts, delta: float):
        host = [t.detach().numpy() for t in (pred, target, parts)]
        terms, g_rgb, g_parts = kernel.image_huber(*host, delta, torch.get_num_threads())
        ctx.save_for_backward(torch.from_numpy(g_rgb), torch.from_numpy(g_parts))
        return tuple(torch.tensor(t, dtype=torch.float32) for t in terms)

    @staticmethod
    @once_differentiable
    def backward(ctx, g_rgb, g_parts):
        d_rgb, d_parts = ctx.saved_tensors
        return d_rgb * g_rgb + d_parts * g_parts, None, None, None
