"""Gaussian splat rendering: a C++ CPU kernel (C ABI, ctypes), its torch autograd wrapper,
gsplat on CUDA, and slow reference renderers for the tests.

Gaussians travel as one container, `frame.SplatFrame` (named fields, the PLY's order).
Importing this package loads neither torch nor the kernel: `frame`, `kernel`, `sh` and
`blender_render` are numpy only (Blender uses them); `rasterization` and `rasterize_frame`
(torch) are imported on first access.
"""

from __future__ import annotations

__all__ = ["rasterization", "rasterize_frame", "Rendered"]


def __getattr__(name):
    if name in __all__:
        from . import rendering

        return getattr(rendering, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
