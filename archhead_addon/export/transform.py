"""Gaussians moved by a similarity transform (rotation, uniform scale, translation), e.g. from
FLAME space into Blender's world for export: means and orientations turn, log scales shift,
and the view-dependent SH bands are rotated too, so the colours seen from a direction stay.
"""

from __future__ import annotations

import numpy as np

from ..avatar.gaussians import quat_multiply
from ..rotations import matrix_to_quaternion
from ..splat.frame import SplatFrame
from ..splat.sh import degree_from_coeffs, sh_basis


def _fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    r = np.sqrt(1 - z * z)
    phi = np.pi * (1 + 5**0.5) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def sh_rotation(rotation: np.ndarray, degree: int) -> np.ndarray:
    """(K,K) block-diagonal M with coefficients c' = M c of the function f(R^T d).

    Each band l is closed under rotation, so its block is the exact least-squares solution
    of Y_l(d) M_l = Y_l(R^T d) over more sample directions than the band has functions."""
    dirs = _fibonacci_sphere(64)
    turned = dirs @ np.asarray(rotation, np.float64)  # rows R^T d
    a = np.stack(sh_basis(degree, *dirs.T), axis=1)
    b = np.stack(sh_basis(degree, *turned.T), axis=1)
    k = (degree + 1) ** 2
    out = np.zeros((k, k))
    for band in range(degree + 1):
        cols = slice(band * band, (band + 1) ** 2)
        out[cols, cols] = np.linalg.lstsq(a[:, cols], b[:, cols], rcond=None)[0]
    return out


def similarity_parts(matrix) -> tuple[float, np.ndarray, np.ndarray]:
    """(scale, rotation (3,3), translation (3,)) of a 4x4 similarity; ValueError otherwise."""
    m = np.asarray(matrix, np.float64)
    linear = m[:3, :3]
    scale = float(np.cbrt(np.linalg.det(linear)))
    rotation = linear / scale if scale > 0 else linear
    if scale <= 0 or not np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-5):
        raise ValueError(
            "Gaussians can only be moved by a rotation, a uniform scale and a "
            "translation (this transform shears, mirrors or scales unevenly)"
        )
    return scale, rotation, m[:3, 3]


def transform_gaussians(matrix, means, log_scales, quats, sh) -> tuple[np.ndarray, ...]:
    """(means, log_scales, quats, sh) after `matrix` (float32)."""
    scale, rotation, translation = similarity_parts(matrix)
    sh = np.asarray(sh, np.float64)
    turn = sh_rotation(rotation, degree_from_coeffs(sh.shape[1]))
    q = quat_multiply(matrix_to_quaternion(rotation)[None], np.asarray(quats, np.float64))
    f32 = np.float32
    return (
        (np.asarray(means, np.float64) @ (scale * rotation).T + translation).astype(f32),
        (np.asarray(log_scales, np.float64) + np.log(scale)).astype(f32),
        q.astype(f32),
        np.einsum("ij,njc->nic", turn, sh).astype(f32),
    )


def transform_frame(matrix, frame: SplatFrame) -> SplatFrame:
    """The frame after `matrix` (opacities unchanged), fields matched by name."""
    means, log_scales, quats, sh = transform_gaussians(
        matrix, frame.means, frame.log_scales, frame.quats, frame.sh
    )
    return SplatFrame(
        means=means,
        log_scales=log_scales,
        quats=quats,
        opacity_logits=frame.opacity_logits,
        sh=sh,
        resolution=frame.resolution,
    )
