"""The decoder's output for one frame, in the conventions of the 3DGS PLY.

Positions in FLAME world space (metres, y up); `log_scales` are log standard deviations;
`quats` are unit w, x, y, z; `opacity_logits` pass through a sigmoid; `sh` is (N, 16, 3) with
the DC term first (colour = 0.5 + C0 * sh[:, 0] + ...). Arrays are numpy (runtime) or torch
(model); the splat kernel consumes either.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

SH_C0 = 0.28209479177387814  # Y_0^0; the DC coefficient of an RGB c is (c - 0.5) / SH_C0


@dataclass
class Gaussians:
    means: Any  # (N,3)
    log_scales: Any  # (N,3)
    quats: Any  # (N,4) w, x, y, z
    opacity_logits: Any  # (N,)
    sh: Any  # (N,16,3)
    offsets: Any  # (N,3) the decoded offsets from the UV surface (head space), for L_mu
    uv_texel: Any  # (N,) int64, row * resolution + col of each Gaussian's texel
    resolution: int  # S

    def __len__(self) -> int:
        return len(self.uv_texel)


def quat_multiply(a, b, stack=np.stack):
    """Hamilton product a * b of w, x, y, z quaternions (numpy, or torch with torch.stack)."""
    aw, ax, ay, az = (a[..., i] for i in range(4))
    bw, bx, by, bz = (b[..., i] for i in range(4))
    return stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        -1,
    )
