"""Real spherical harmonics (degree 0-3) to RGB, as 3DGS: rgb = max(SH . basis(dir) + 0.5, 0).

Coefficients are (..., K, 3) with K = (degree + 1)^2 in the standard 3DGS order (the PLY's
f_dc then f_rest, channel-major there, coefficient-major here). `sh_to_rgb_numpy` serves
Blender (numpy only); `sh_to_rgb_torch` serves training. Both share `sh_basis`, written with
plain arithmetic so it runs on numpy arrays and torch tensors alike.
"""

from __future__ import annotations

import math

import numpy as np

C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
      0.5462742152960396)  # fmt: skip
C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
      -0.4570457994644658, 1.445305721320277, -0.5900435899266435)  # fmt: skip

_DIR_EPS = 1e-12  # direction-norm guard (as F.normalize)


def degree_from_coeffs(k: int) -> int:
    d = math.isqrt(k) - 1
    if (d + 1) ** 2 != k or not 0 <= d <= 3:
        raise ValueError(f"SH coefficient count must be 1, 4, 9 or 16, got {k}")
    return d


def sh_basis(degree: int, x, y, z) -> list:
    """The (degree + 1)^2 basis values at unit directions (x, y, z)."""
    out = [C0 + 0.0 * x]
    if degree >= 1:
        out += [-C1 * y, C1 * z, -C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        out += [
            C2[0] * x * y,
            C2[1] * y * z,
            C2[2] * (2.0 * zz - xx - yy),
            C2[3] * x * z,
            C2[4] * (xx - yy),
        ]
    if degree >= 3:
        out += [
            C3[0] * y * (3.0 * xx - yy),
            C3[1] * x * y * z,
            C3[2] * y * (4.0 * zz - xx - yy),
            C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            C3[4] * x * (4.0 * zz - xx - yy),
            C3[5] * z * (xx - yy),
            C3[6] * x * (xx - 3.0 * yy),
        ]
    return out


def _check(degree: int, coeffs_shape) -> None:
    if not 0 <= degree <= 3:
        raise ValueError(f"sh_degree must be 0..3, got {degree}")
    if coeffs_shape[-1] != 3 or coeffs_shape[-2] < (degree + 1) ** 2:
        raise ValueError(
            f"SH coefficients must be (..., K>={(degree + 1) ** 2}, 3), got {tuple(coeffs_shape)}"
        )


def sh_to_rgb_numpy(degree: int, dirs: np.ndarray, coeffs: np.ndarray) -> np.ndarray:
    """RGB (..., 3) for view directions dirs (..., 3) (any length) and coeffs (..., K, 3)."""
    _check(degree, coeffs.shape)
    dirs = dirs / np.maximum(np.linalg.norm(dirs, axis=-1, keepdims=True), _DIR_EPS)
    basis = sh_basis(degree, dirs[..., 0], dirs[..., 1], dirs[..., 2])
    rgb = sum(b[..., None] * coeffs[..., k, :] for k, b in enumerate(basis))
    return np.maximum(rgb + 0.5, 0.0)


def sh_to_rgb_torch(degree: int, dirs, coeffs):
    """Torch version of sh_to_rgb_numpy (differentiable in dirs and coeffs)."""
    _check(degree, coeffs.shape)
    dirs = dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(_DIR_EPS)
    basis = sh_basis(degree, dirs[..., 0], dirs[..., 1], dirs[..., 2])
    rgb = sum(b[..., None] * coeffs[..., k, :] for k, b in enumerate(basis))
    return (rgb + 0.5).clamp_min(0.0)
