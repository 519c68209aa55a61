"""sRGB encoding, and where colours are blended.

3DGS blends the Gaussians' colours as display (sRGB) values. Blender blends scene-linear
values and encodes the result, so an avatar trained with display-space blending cannot look
the same in Blender wherever Gaussians of different colours overlap: on the real avatar that
gap alone held Cycles to 25-28 dB against the exact splat render. Avatars whose config says
`colour_space = "linear"` (the default since) treat their colours as linear, blend them so
in every renderer (training, evaluation, the exact splat render) and encode the image at the
end, as Blender does: what Blender shows is then what was trained (docs/blender_avatar.md).
"""

from __future__ import annotations

import numpy as np

_TINY = 1e-7  # keeps the gradient of c^(1/2.4) finite at 0


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c: np.ndarray) -> np.ndarray:
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)


def linear_to_srgb_torch(c):
    """Differentiable linear_to_srgb for torch tensors: a float32 CPU tensor by the splat
    kernel in one pass, others in torch."""
    from .autograd import SrgbEncodeCPU, cpu_float32

    return SrgbEncodeCPU.apply(c) if cpu_float32(c) else linear_to_srgb_ops(c)


def linear_to_srgb_ops(c):
    """linear_to_srgb in torch operations: on other devices, and the reference the kernel's
    is held to (tests/test_colour_space.py)."""
    import torch

    c = c.clamp(0.0, 1.0)
    curve = 1.055 * c.clamp_min(_TINY) ** (1 / 2.4) - 0.055
    return torch.where(c <= 0.0031308, 12.92 * c, curve)


def display_background(background, colour_space: str):
    """The background as the renderer blends it: linearised for a linear avatar."""
    bg = np.asarray(background, np.float64)
    return srgb_to_linear(bg) if colour_space == "linear" else bg


def straight_display(premultiplied_rgb: np.ndarray, alpha: np.ndarray, colour_space: str):
    """A render over nothing (premultiplied, background 0) as straight-alpha display values,
    as Blender writes a transparent film: colour / alpha, then encoded if linear."""
    straight = premultiplied_rgb / np.maximum(alpha, 1e-6)[..., None]
    return linear_to_srgb(straight) if colour_space == "linear" else straight


def sh_as_display(sh: np.ndarray) -> np.ndarray:
    """A linear avatar's SH coefficients (N, K, 3) as display-space ones, for files read by
    3DGS tools (they blend display values): the DC colour encoded exactly, the higher bands
    scaled by the encoding's slope there (first order)."""
    from .sh import C0

    sh = np.asarray(sh, np.float32)
    linear = np.maximum(0.5 + C0 * sh[:, 0], 0.0)
    out = sh.copy()
    out[:, 0] = (linear_to_srgb(linear) - 0.5) / C0
    if sh.shape[1] > 1:
        step = 1e-4
        slope = (linear_to_srgb(linear + step) - linear_to_srgb(linear)) / step
        out[:, 1:] *= slope[:, None]
    return out
