"""Bicubic resizing in numpy that reproduces torch's F.interpolate(mode="bicubic",
align_corners=False, antialias=False): Keys' cubic with a = -0.75, taps outside the map
clamped to the border (edge replication), no anti-aliasing when shrinking.

Rounding follows PyTorch's CPU kernel: float32 arithmetic, and the source coordinate
scale * (i + 0.5) - 0.5 rounded once, as the fused multiply-add its compiled loop uses.
"""

from __future__ import annotations

import numpy as np

A = np.float32(-0.75)


def _near(t):  # |x| <= 1
    return ((A + 2) * t - (A + 3)) * t * t + 1


def _far(t):  # 1 < |x| < 2
    return ((A * t - 5 * A) * t + 8 * A) * t - 4 * A


def taps(n_in: int, n_out: int) -> tuple[np.ndarray, np.ndarray]:
    """(index (n_out, 4), weight (n_out, 4) float32): the four source samples of every output
    along one axis, indices clamped to the border."""
    scale = np.float32(n_in) / np.float32(n_out)
    real = (np.float64(scale) * (np.arange(n_out) + 0.5) - 0.5).astype(np.float32)
    i0 = np.floor(real).astype(np.int64)
    t = real - i0.astype(np.float32)
    one = np.float32(1)
    weight = np.stack([_far(t + one), _near(t), _near(one - t), _far(2 * one - t)], axis=1)
    return np.clip(i0[:, None] + np.arange(-1, 3), 0, n_in - 1), weight


def resize_matrix(n_in: int, n_out: int) -> np.ndarray:
    """(n_out, n_in) float32 matrix M with out = M @ in along one axis."""
    idx, weight = taps(n_in, n_out)
    m = np.zeros((n_out, n_in), dtype=np.float32)
    np.add.at(m, (np.repeat(np.arange(n_out), 4), idx.ravel()), weight.ravel())
    return m


def resize(maps: np.ndarray, size: int) -> np.ndarray:
    """(C, H, W) -> (C, size, size) float32. Two dense matrix products (the columns, then the
    rows): BLAS beats gathering the four taps at these sizes."""
    maps = maps.astype(np.float32, copy=False)
    _, h, w = maps.shape
    if (h, w) == (size, size):
        return maps
    return resize_matrix(h, size) @ (maps @ resize_matrix(w, size).T)
