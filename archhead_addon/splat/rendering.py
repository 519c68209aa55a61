"""The one public render call for training: gsplat on CUDA when available, else the CPU kernel.

`rasterize_frame` takes a `SplatFrame` of tensors; `rasterization` takes gsplat's
`rasterization()` arguments in gsplat's order and axes (quats before log_scales, `colors`),
with ArchHead's storage conventions for the activations (so checkpoints feed it without
conversion), and passes them on as a SplatFrame:

  means (N,3)            world positions
  log_scales (N,3)       natural log of the scales (clamped to [-23, 11.5] before exp)
  quats (N,4)            w, x, y, z; any length (normalised inside; zero -> identity)
  opacity_logits (N,)    opacity = sigmoid(logit)
  sh (N,3) | (N,K,3)     (gsplat: colors) RGB, or SH coefficients with K = (sh_degree + 1)^2
                         evaluated for the direction from the camera centre to each mean
                         (3DGS: +0.5, >= 0)
  viewmat (4,4)          world-to-camera, OpenCV axes (x right, y down, z forward)
  K (3,3)                intrinsics in pixels; pixel (i, j) is centred at (i + 0.5, j + 0.5)

Returns `Rendered(rgb (H,W,3), alpha (H,W,1), depth (H,W,1))`: rgb composited over the
background, alpha = 1 - final transmittance, depth the expected camera z
(sum_i w_i z_i / alpha, 0 where alpha is 0; gsplat's "ED").

Numerics shared by both back ends: EWA projection with the 2D covariance dilated by eps2d,
optional antialiased opacity compensation (rasterize_mode="antialiased"), alpha skipped below
1/255, near/far culling. The CPU kernel follows 3DGS for the rest (alpha clamp 0.99, stop
below transmittance 1e-4, opacity-aware tile bounds); gsplat 1.5 clamps alpha at 0.999 and
bounds tiles at 3.33 sigma, so the two back ends differ slightly on saturated pixels.
"""

from __future__ import annotations

import importlib.util
from dataclasses import replace
from typing import Literal, NamedTuple

import numpy as np
import torch

from . import kernel
from .autograd import splat_cpu
from .frame import SplatFrame, from_gsplat_order
from .sh import degree_from_coeffs, sh_to_rgb_torch

Backend = Literal["auto", "cpu", "gsplat"]


class Rendered(NamedTuple):
    rgb: torch.Tensor  # (H,W,3)
    alpha: torch.Tensor  # (H,W,1)
    depth: torch.Tensor  # (H,W,1) expected camera z


def gsplat_available() -> bool:
    return torch.cuda.is_available() and importlib.util.find_spec("gsplat") is not None


def select_backend(backend: Backend, device: torch.device) -> Literal["cpu", "gsplat"]:
    if backend == "cpu":
        return "cpu"
    if backend == "gsplat":
        if not gsplat_available() or device.type != "cuda":
            raise RuntimeError("backend='gsplat' needs CUDA tensors and the gsplat package")
        return "gsplat"
    if backend != "auto":
        raise ValueError(f"backend must be 'auto', 'cpu' or 'gsplat', got {backend!r}")
    return "gsplat" if device.type == "cuda" and gsplat_available() else "cpu"


def camera_center(viewmat: torch.Tensor) -> torch.Tensor:
    return torch.linalg.inv(viewmat)[:3, 3]


def resolve_colors(colors, means, viewmat, sh_degree):
    """Per-Gaussian RGB: colors as given, or SH evaluated towards the camera."""
    if colors.ndim == 2:
        return colors
    if sh_degree is None:
        sh_degree = degree_from_coeffs(colors.shape[-2])
    dirs = means - camera_center(viewmat.to(means))
    return sh_to_rgb_torch(sh_degree, dirs, colors)


def rasterization(
    means: torch.Tensor,
    quats: torch.Tensor,
    log_scales: torch.Tensor,
    opacity_logits: torch.Tensor,
    colors: torch.Tensor,
    viewmat,
    K,
    width: int,
    height: int,
    **options,
) -> Rendered:
    """`rasterize_frame` with gsplat's argument order (see the module docstring)."""
    frame = from_gsplat_order(means, quats, log_scales, opacity_logits, colors)
    return rasterize_frame(frame, viewmat, K, width, height, **options)


def rasterize_frame(
    frame: SplatFrame,
    viewmat,
    K,
    width: int,
    height: int,
    *,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    eps2d: float = 0.3,
    sh_degree: int | None = None,
    background=None,
    rasterize_mode: Literal["classic", "antialiased"] = "classic",
    backend: Backend = "auto",
    num_threads: int = 0,
) -> Rendered:
    """Render one camera (see the module docstring for the conventions)."""
    if rasterize_mode not in ("classic", "antialiased"):
        raise ValueError(f"rasterize_mode must be 'classic' or 'antialiased': {rasterize_mode!r}")
    device = frame.means.device
    # float64 on the host for the CPU kernel (it projects in double); float32 on the device
    viewmat64, K64 = (
        np.asarray(torch.as_tensor(x).detach().cpu(), np.float64) for x in (viewmat, K)
    )
    viewmat = torch.as_tensor(viewmat64, dtype=torch.float32, device=device)
    K = torch.as_tensor(K64, dtype=torch.float32, device=device)
    bg = torch.zeros(3) if background is None else torch.as_tensor(background).float().cpu()
    frame = replace(frame, sh=resolve_colors(frame.sh, frame.means, viewmat, sh_degree))

    if select_backend(backend, device) == "gsplat":
        return _rasterize_gsplat(
            frame, viewmat, K, width, height, near_plane, far_plane, eps2d, bg.to(device),
            rasterize_mode,
        )  # fmt: skip

    settings = kernel.RasterSettings(
        viewmat=viewmat64,
        K=K64,
        width=width,
        height=height,
        near_plane=near_plane,
        far_plane=far_plane,
        eps2d=eps2d,
        antialiased=rasterize_mode == "antialiased",
        background=tuple(np.asarray(bg, dtype=np.float64).tolist()),
        num_threads=num_threads,
    )
    rgb, alpha, depth_acc = splat_cpu(frame, settings)
    alpha = alpha[..., None]
    return Rendered(rgb, alpha, depth_acc[..., None] / alpha.clamp_min(1e-10))


def _rasterize_gsplat(
    frame, viewmat, K, width, height, near_plane, far_plane, eps2d, bg, rasterize_mode,
) -> Rendered:  # fmt: skip
    import gsplat

    for name, t in frame.arrays().items():
        if not torch.isfinite(t).all():
            raise ValueError(f"{name} contains non-finite values (NaN or Inf)")
    scales = frame.log_scales.clamp(kernel.LOG_SCALE_MIN, kernel.LOG_SCALE_MAX).exp()
    colors, alphas, _ = gsplat.rasterization(
        means=frame.means, quats=frame.quats, scales=scales,
        opacities=torch.sigmoid(frame.opacity_logits), colors=frame.sh, viewmats=viewmat[None],
        Ks=K[None], width=width, height=height, near_plane=near_plane, far_plane=far_plane,
        eps2d=eps2d, packed=False, render_mode="RGB+ED", rasterize_mode=rasterize_mode,
    )  # fmt: skip
    alpha = alphas[0]
    rgb_out = colors[0, ..., :3] + (1.0 - alpha) * bg
    return Rendered(rgb_out, alpha, colors[0, ..., 3:4])
