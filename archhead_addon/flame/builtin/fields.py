"""Smooth scalar and vector fields over head positions, shared by the sculpt, rig and bases."""

from __future__ import annotations

import numpy as np


def smoothstep(x, lo, hi):
    t = np.clip((x - lo) / (hi - lo), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def bump(p, centre, radii):
    """1 at the centre, 0 outside the ellipsoid, smooth (C2) in between."""
    q = (np.asarray(p) - centre) / radii
    return np.clip(1.0 - (q * q).sum(-1), 0.0, 1.0) ** 3


def mirrored(p):
    """Points with |x|, so paired features are written once, for the subject's left."""
    return np.concatenate([np.abs(p[..., :1]), p[..., 1:]], axis=-1)


def side(p):
    """+1 on the subject's left (x > 0), -1 on the right, as a column for vector fields."""
    return np.where(p[..., :1] >= 0, 1.0, -1.0)


def random_smooth_fields(p, n, seed, wavelengths, symmetric, chunk=16):
    """n smooth random vector fields on points p (V,3), each with unit RMS, (V,3,n).

    Each axis of field k is a sum of 6 random plane waves of wavelength wavelengths[k]
    (metres), so nearby points move together. `symmetric` mirrors each field across x = 0
    (x odd, y and z even). Plain elementwise numpy (no BLAS): the bytes do not depend on
    thread counts. The waves are summed in float32 (fast, and the model is stored in it).
    """
    rng = np.random.default_rng(seed)
    n_waves = 6
    dirs = rng.normal(size=(n, 3, n_waves, 3))
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    dirs *= (2 * np.pi / np.asarray(wavelengths, dtype=np.float64))[:, None, None, None]
    phase = rng.uniform(0, 2 * np.pi, size=(n, 3, n_waves))
    amp = rng.normal(size=(n, 3, n_waves))
    dirs, phase, amp = (a.astype(np.float32) for a in (dirs, phase, amp))
    x, y, z = (p[:, c, None, None, None].astype(np.float32) for c in range(3))
    out = np.empty((len(p), 3, n))
    for k0 in range(0, n, chunk):
        k = slice(k0, min(k0 + chunk, n))
        along_x = x * dirs[k, :, :, 0]  # (V, chunk, 3, W)
        rest = y * dirs[k, :, :, 1] + z * dirs[k, :, :, 2] + phase[k]
        f = np.cos(along_x + rest)
        if symmetric:
            parity = np.array([-1.0, 1.0, 1.0], np.float32)[:, None]
            f = 0.5 * (f + parity * np.cos(rest - along_x))
        f = (amp[k] * f).sum(-1, dtype=np.float64)  # (V, chunk, 3)
        out[:, :, k] = (f / np.sqrt((f * f).sum(-1).mean(0))[:, None]).transpose(0, 2, 1)
    return out
