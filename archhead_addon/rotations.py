"""Rotation conversions, one implementation for numpy arrays and torch tensors.

Conventions: axis-angle vectors (..., 3); rotation matrices (..., 3, 3) acting on column
vectors; quaternions (..., 4) as w, x, y, z; the 6D form is the first two *rows* of the
matrix (the PyTorch3D layout that metrical-tracker writes), completed by Gram-Schmidt.
Every function is stable at angle 0 (Taylor branches, so torch gradients are finite too)
and at angle pi (matrix -> quaternion picks the largest pivot).
"""

from __future__ import annotations

import numpy as np

_SMALL = 1e-4  # below this angle (rad) the Taylor series are exact to float64 rounding


class _Ops:
    """The handful of array operations that differ between numpy and torch."""

    def __init__(self, like):
        self.torch = not isinstance(like, np.ndarray | np.generic | float | int)
        if self.torch:
            import torch

            self.m = torch
        else:
            self.m = np

    def asarray(self, x):
        return x if self.torch else np.asarray(x, dtype=np.result_type(x, np.float32))

    def stack(self, xs, axis):
        return self.m.stack(xs, axis) if not self.torch else self.m.stack(xs, dim=axis)

    def cat(self, xs, axis):
        return np.concatenate(xs, axis) if not self.torch else self.m.cat(xs, dim=axis)

    def sum(self, x, axis, keep=False):
        return x.sum(axis, keepdims=keep) if not self.torch else x.sum(axis, keepdim=keep)

    def atan2(self, y, x):
        return np.arctan2(y, x) if not self.torch else self.m.atan2(y, x)

    def clip(self, x, lo, hi):
        return np.clip(x, lo, hi) if not self.torch else x.clamp(lo, hi)

    def cross(self, a, b):
        return np.cross(a, b) if not self.torch else self.m.linalg.cross(a, b, dim=-1)

    def argmax(self, x, axis):
        return x.argmax(axis) if not self.torch else x.argmax(dim=axis)

    def take(self, x, idx, axis):
        """x[..., idx[...], ...] along `axis` with idx broadcast to x's other dims."""
        if self.torch:
            return self.m.take_along_dim(x, idx, dim=axis)
        return np.take_along_axis(x, idx, axis=axis)


def _sinc_terms(theta2, ops):
    """sin(t)/t and (1 - cos t)/t^2 from t^2, exact near zero and differentiable there."""
    m = ops.m
    small = theta2 < _SMALL**2
    safe2 = m.where(small, m.ones_like(theta2), theta2)
    t = m.sqrt(safe2)
    a = m.where(small, 1 - theta2 / 6 + theta2**2 / 120, m.sin(t) / t)
    b = m.where(small, 0.5 - theta2 / 24 + theta2**2 / 720, (1 - m.cos(t)) / safe2)
    return a, b


def axis_angle_to_matrix(aa):
    """Rodrigues: R = I + a [k]x + b [k]x^2 with a = sin t / t, b = (1 - cos t) / t^2."""
    ops = _Ops(aa)
    aa = ops.asarray(aa)
    x, y, z = aa[..., 0], aa[..., 1], aa[..., 2]
    a, b = _sinc_terms(x * x + y * y + z * z, ops)
    xx, yy, zz, xy, xz, yz = x * x, y * y, z * z, x * y, x * z, y * z
    rows = [
        [1 - b * (yy + zz), b * xy - a * z, b * xz + a * y],
        [b * xy + a * z, 1 - b * (xx + zz), b * yz - a * x],
        [b * xz - a * y, b * yz + a * x, 1 - b * (xx + yy)],
    ]
    return ops.stack([ops.stack(r, -1) for r in rows], -2)


def quaternion_to_matrix(q):
    """Unit quaternion (w, x, y, z) to matrix; q is normalised first (a zero q gives I)."""
    ops = _Ops(q)
    q = ops.asarray(q)
    n2 = ops.sum(q * q, -1, keep=True)
    q = q / ops.m.sqrt(ops.m.where(n2 > 0, n2, ops.m.ones_like(n2)))
    q = ops.m.where(n2 > 0, q, q * 0 + _identity_quat(ops, q))
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return ops.stack([ops.stack(r, -1) for r in rows], -2)


def _identity_quat(ops, like):
    if ops.torch:
        return ops.m.tensor([1.0, 0.0, 0.0, 0.0], dtype=like.dtype, device=like.device)
    return np.array([1.0, 0.0, 0.0, 0.0], dtype=like.dtype)


def matrix_to_quaternion(R):
    """Shepperd's method: take the largest of 4w^2, 4x^2, 4y^2, 4z^2 as pivot (stable at pi).

    Returns w >= 0.
    """
    ops = _Ops(R)
    R = ops.asarray(R)
    m = ops.m
    r00, r11, r22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    r01, r02, r10, r12, r20, r21 = (
        R[..., 0, 1],
        R[..., 0, 2],
        R[..., 1, 0],
        R[..., 1, 2],
        R[..., 2, 0],
        R[..., 2, 1],
    )
    # Each candidate is 4 * pivot * (w, x, y, z) for one choice of pivot.
    cand = ops.stack(
        [
            ops.stack([1 + r00 + r11 + r22, r21 - r12, r02 - r20, r10 - r01], -1),
            ops.stack([r21 - r12, 1 + r00 - r11 - r22, r01 + r10, r02 + r20], -1),
            ops.stack([r02 - r20, r01 + r10, 1 - r00 + r11 - r22, r12 + r21], -1),
            ops.stack([r10 - r01, r02 + r20, r12 + r21, 1 - r00 - r11 + r22], -1),
        ],
        -2,
    )
    pivots = ops.stack([cand[..., 0, 0], cand[..., 1, 1], cand[..., 2, 2], cand[..., 3, 3]], -1)
    best = ops.argmax(pivots, -1)
    idx = best[..., None, None]
    idx = idx.expand(*best.shape, 1, 4) if ops.torch else np.broadcast_to(idx, (*best.shape, 1, 4))
    q = ops.take(cand, idx, -2)[..., 0, :]
    q = q / m.sqrt(ops.sum(q * q, -1, keep=True))
    return m.where(q[..., :1] < 0, -q, q)


def quaternion_to_axis_angle(q):
    """angle = 2 atan2(|v|, w) about v / |v|, with w >= 0; Taylor branch near zero."""
    ops = _Ops(q)
    q = ops.asarray(q)
    m = ops.m
    q = m.where(q[..., :1] < 0, -q, q)
    w, v = q[..., :1], q[..., 1:]
    s2 = ops.sum(v * v, -1, keep=True)
    small = s2 < _SMALL**2
    s = m.sqrt(m.where(small, m.ones_like(s2), s2))
    w_safe = m.where(small, w, m.ones_like(w))  # a unit q with tiny |v| has w close to 1
    factor = m.where(small, 2 / w_safe * (1 - s2 / (3 * w_safe * w_safe)), 2 * ops.atan2(s, w) / s)
    return v * factor


def axis_angle_to_quaternion(aa):
    ops = _Ops(aa)
    aa = ops.asarray(aa)
    m = ops.m
    t2 = ops.sum(aa * aa, -1, keep=True)
    small = t2 < _SMALL**2
    t = m.sqrt(m.where(small, m.ones_like(t2), t2))
    half_sinc = m.where(small, 0.5 - t2 / 48, m.sin(t / 2) / t)  # sin(t/2)/t
    w = m.where(small, 1 - t2 / 8, m.cos(t / 2))
    return ops.cat([w, aa * half_sinc], -1)


def matrix_to_axis_angle(R):
    return quaternion_to_axis_angle(matrix_to_quaternion(R))


def rotation_6d_to_matrix(d6):
    """6D (first two rows, PyTorch3D layout) to matrix by Gram-Schmidt."""
    ops = _Ops(d6)
    d6 = ops.asarray(d6)
    m = ops.m
    a1, a2 = d6[..., :3], d6[..., 3:6]
    n1 = m.sqrt(ops.clip(ops.sum(a1 * a1, -1, keep=True), 1e-24, None))
    b1 = a1 / n1
    b2 = a2 - ops.sum(b1 * a2, -1, keep=True) * b1
    n2 = m.sqrt(ops.clip(ops.sum(b2 * b2, -1, keep=True), 1e-24, None))
    b2 = b2 / n2
    b3 = ops.cross(b1, b2)
    return ops.stack([b1, b2, b3], -2)


def matrix_to_rotation_6d(R):
    lead = R.shape[:-2]
    return R[..., :2, :].reshape(*lead, 6)
