"""Plain PyTorch renderers with the kernel's rules, for tests and the benchmark only; they
take a `SplatFrame` of tensors (RGB in sh).

`render_reference` evaluates every Gaussian at every pixel, front to back, in whatever dtype
it is given (float64 in the tests; torch autograd gives the reference gradients).
`render_tiles_torch` is the usual pure-torch tile renderer (dense alpha matrix per 16x16 tile,
cumprod transmittance) that the splat benchmark (benchmarks/splat_kernel.py) compares the
kernel against.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from .frame import SplatFrame
from .kernel import LOG_SCALE_MAX, LOG_SCALE_MIN

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
TRANSMITTANCE_MIN = 1e-4
DET_MIN = 1e-10
TILE = 16


class Projection(NamedTuple):
    ids: torch.Tensor  # (M,) indices of the Gaussians that survive culling
    means2d: torch.Tensor  # (M,2)
    conics: torch.Tensor  # (M,3) a, b, c of [[a,b],[b,c]]
    depths: torch.Tensor  # (M,)
    opacities: torch.Tensor  # (M,)
    cov2d: torch.Tensor  # (M,2,2) dilated


def quat_to_rotmat(q: torch.Tensor) -> torch.Tensor:
    q = q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = q.unbind(-1)
    R = torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    )  # fmt: skip
    return R.reshape(q.shape[:-1] + (3, 3))


def _project(g: SplatFrame, viewmat, K, width, height, eps2d, antialiased):
    R = quat_to_rotmat(g.quats)
    M = R * g.log_scales.clamp(LOG_SCALE_MIN, LOG_SCALE_MAX).exp()[..., None, :]
    V, t = viewmat[:3, :3], viewmat[:3, 3]
    tc = g.means @ V.T + t
    Sc = V @ (M @ M.transpose(-1, -2)) @ V.T
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    tan_x, tan_y = 0.5 * width / fx, 0.5 * height / fy
    tz = tc[:, 2]
    tx = tz * (tc[:, 0] / tz).clamp(-(cx / fx + 0.3 * tan_x), (width - cx) / fx + 0.3 * tan_x)
    ty = tz * (tc[:, 1] / tz).clamp(-(cy / fy + 0.3 * tan_y), (height - cy) / fy + 0.3 * tan_y)
    zero = torch.zeros_like(tz)
    J = torch.stack([fx / tz, zero, -fx * tx / tz**2, zero, fy / tz, -fy * ty / tz**2], -1)
    J = J.reshape(-1, 2, 3)
    cov = J @ Sc @ J.transpose(-1, -2)
    det_orig = cov[:, 0, 0] * cov[:, 1, 1] - cov[:, 0, 1] * cov[:, 1, 0]
    covd = cov + eps2d * torch.eye(2, dtype=cov.dtype)
    det = covd[:, 0, 0] * covd[:, 1, 1] - covd[:, 0, 1] * covd[:, 1, 0]
    conics = torch.stack([covd[:, 1, 1] / det, -covd[:, 0, 1] / det, covd[:, 0, 0] / det], -1)
    opacity = torch.sigmoid(g.opacity_logits)
    if antialiased:
        opacity = opacity * (det_orig / det).clamp_min(0.0).sqrt()
    means2d = torch.stack([fx * tc[:, 0] / tz + cx, fy * tc[:, 1] / tz + cy], -1)
    return means2d, conics, tz, opacity, covd, det


def project_reference(g: SplatFrame, viewmat, K, width, height, *, near_plane=0.01,
                      far_plane=1e10, eps2d=0.3, antialiased=False) -> Projection:  # fmt: skip
    """Differentiable projection of a frame's Gaussians that survive the kernel's culling."""
    viewmat, K = viewmat.to(g.means), K.to(g.means)
    args = (viewmat, K, width, height, eps2d, antialiased)
    with torch.no_grad():  # decide culling first so culled rows never enter the graph
        _, _, tz, opacity, _, det = _project(g, *args)
        keep = (tz > near_plane) & (tz < far_plane)
        keep &= torch.nan_to_num(det, nan=0.0) > DET_MIN
        keep &= torch.nan_to_num(opacity, nan=0.0) >= ALPHA_MIN
        ids = keep.nonzero().flatten()
    means2d, conics, tz, opacity, covd, _ = _project(g.map(lambda a: a[ids]), *args)
    return Projection(ids, means2d, conics, tz, opacity, covd)


class Image(NamedTuple):
    rgb: torch.Tensor  # (H,W,3)
    alpha: torch.Tensor  # (H,W)
    depth: torch.Tensor  # (H,W) accumulated sum_i w_i z_i


def _alpha(P: Projection, k, dx, dy):
    a, b, c = P.conics[k].unbind(-1)
    power = -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy
    alpha = (P.opacities[k] * torch.exp(power)).clamp(max=ALPHA_MAX)
    return alpha, (power <= 0) & (alpha >= ALPHA_MIN)


def render_reference(g: SplatFrame, viewmat, K, width, height, *, near_plane=0.01,
                     far_plane=1e10, eps2d=0.3, antialiased=False,
                     background=(0.0, 0.0, 0.0)) -> Image:  # fmt: skip
    """Every Gaussian of a frame (RGB in sh) at every pixel, front to back (slow; small
    images only)."""
    P = project_reference(g, viewmat, K, width, height, near_plane=near_plane,
                          far_plane=far_plane, eps2d=eps2d, antialiased=antialiased)  # fmt: skip
    dtype = g.means.dtype
    ys, xs = torch.meshgrid(torch.arange(height, dtype=dtype) + 0.5,
                            torch.arange(width, dtype=dtype) + 0.5, indexing="ij")  # fmt: skip
    xs, ys = xs.reshape(-1), ys.reshape(-1)
    T = torch.ones_like(xs)
    rgb = torch.zeros(xs.shape + (3,), dtype=dtype)
    depth = torch.zeros_like(xs)
    live = torch.ones_like(xs, dtype=torch.bool)
    cols = g.sh[P.ids]
    for k in torch.argsort(P.depths.detach(), stable=True).tolist():
        alpha, ok = _alpha(P, k, P.means2d[k, 0] - xs, P.means2d[k, 1] - ys)
        ok &= live
        next_T = T * (1 - alpha)
        stop = ok & (next_T < TRANSMITTANCE_MIN)
        use = ok & ~stop
        w = torch.where(use, alpha * T, torch.zeros_like(T))
        rgb = rgb + w[:, None] * cols[k]
        depth = depth + w * P.depths[k]
        T = torch.where(use, next_T, T)
        live = live & ~stop
    bg = torch.as_tensor(background, dtype=dtype)
    rgb = rgb + T[:, None] * bg
    return Image(rgb.reshape(height, width, 3), (1 - T).reshape(height, width),
                 depth.reshape(height, width))  # fmt: skip


def render_tiles_torch(g: SplatFrame, viewmat, K, width, height, *, near_plane=0.01,
                       far_plane=1e10, eps2d=0.3, background=(0.0, 0.0, 0.0)) -> Image:  # fmt: skip
    """Pure-torch tile renderer of a frame (RGB in sh; dense per-tile alpha matrices;
    autograd for gradients)."""
    P = project_reference(
        g, viewmat, K, width, height, near_plane=near_plane, far_plane=far_plane, eps2d=eps2d
    )
    dtype = g.means.dtype
    order = torch.argsort(P.depths.detach(), stable=True)
    P = Projection(*(t[order] for t in P))
    cols, z = g.sh[P.ids], P.depths
    with torch.no_grad():  # opacity-aware bounds, as the kernel
        k = (2 * torch.log(255 * P.opacities.clamp_min(ALPHA_MIN))).sqrt()
        r = k[:, None] * torch.stack([P.cov2d[:, 0, 0], P.cov2d[:, 1, 1]], -1).sqrt()
        lo = ((P.means2d - r - 0.5).ceil().clamp_min(0) // TILE).long()
        hi = ((P.means2d + r - 0.5).floor() // TILE).long()
    bg = torch.as_tensor(background, dtype=dtype)
    tiles_x, tiles_y = -(-width // TILE), -(-height // TILE)
    rows = []
    for ty in range(tiles_y):
        row = []
        for tx in range(tiles_x):
            idx = (lo[:, 0] <= tx) & (hi[:, 0] >= tx) & (lo[:, 1] <= ty) & (hi[:, 1] >= ty)
            idx = idx.nonzero().flatten()
            ys, xs = torch.meshgrid(torch.arange(TILE, dtype=dtype) + ty * TILE + 0.5,
                                    torch.arange(TILE, dtype=dtype) + tx * TILE + 0.5,
                                    indexing="ij")  # fmt: skip
            xs, ys = xs.reshape(-1, 1), ys.reshape(-1, 1)
            alpha, ok = _alpha(P, idx, P.means2d[idx, 0] - xs, P.means2d[idx, 1] - ys)
            alpha = torch.where(ok, alpha, torch.zeros_like(alpha))
            trans = torch.cumprod(1 - alpha, dim=1)
            T = torch.cat([torch.ones_like(trans[:, :1]), trans[:, :-1]], dim=1)
            w = alpha * T * (trans >= TRANSMITTANCE_MIN)
            a = w.sum(1)
            rgb = w @ cols[idx] + (1 - a)[:, None] * bg
            row.append(torch.cat([rgb, a[:, None], (w @ z[idx])[:, None]], -1).reshape(
                TILE, TILE, 5))  # fmt: skip
        rows.append(torch.cat(row, dim=1))
    out = torch.cat(rows, dim=0)[:height, :width]
    return Image(out[..., :3], out[..., 3], out[..., 4])
