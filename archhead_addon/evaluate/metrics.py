"""Image metrics of the paper's tables: L1, PSNR, SSIM (and ST-LPIPS, train/perceptual.py).

Images are torch tensors (H,W,3) in [0, 1]. SSIM follows Wang et al. (2004): an 11x11 Gaussian
window of sigma 1.5, C1 = (0.01)², C2 = (0.03)² for a data range of 1, the local statistics on
the 'valid' windows only (no padding, as the reference MATLAB code), averaged over windows and
channels.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

SSIM_WINDOW, SSIM_SIGMA = 11, 1.5
SSIM_C1, SSIM_C2 = 0.01**2, 0.03**2


def l1(pred: torch.Tensor, target: torch.Tensor) -> float:
    return float((pred - target).abs().mean())


def psnr(pred: torch.Tensor, target: torch.Tensor, region: torch.Tensor | None = None) -> float:
    """10 log10(1 / MSE) in dB (infinite for identical images); with `region` (H,W) weights,
    the MSE over its pixels only (NaN where the region is empty)."""
    error = (pred.double() - target.double()).square().mean(dim=-1)
    if region is None:
        mse = float(error.mean())
    else:
        weight = region.double()
        total = float(weight.sum())
        if total == 0:
            return math.nan
        mse = float((error * weight).sum()) / total
    return math.inf if mse == 0 else 10.0 * math.log10(1.0 / mse)


def gaussian_kernel(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> torch.Tensor:
    """(size,) float64, sums to 1: SSIM's window is its outer product with itself."""
    x = torch.arange(size, dtype=torch.float64) - (size - 1) / 2
    g = torch.exp(-x.square() / (2 * sigma**2))
    return g / g.sum()


def ssim(pred: torch.Tensor, target: torch.Tensor, region: torch.Tensor | None = None) -> float:
    """The mean SSIM over valid windows and channels; with `region` (H,W) weights, over the
    windows centred in it (NaN where none is)."""
    ssim_map = _ssim_map(pred, target).mean(dim=0)  # (H-10, W-10)
    if region is None:
        return float(ssim_map.mean())
    half = SSIM_WINDOW // 2
    weight = region.double()[half : region.shape[0] - half, half : region.shape[1] - half]
    total = float(weight.sum())
    return math.nan if total == 0 else float((ssim_map * weight).sum()) / total


def _ssim_map(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """(C,H-10,W-10) float64: SSIM of each valid window."""
    if pred.shape != target.shape or pred.ndim != 3:
        raise ValueError(
            f"expected two (H,W,C) images, got {tuple(pred.shape)} and {tuple(target.shape)}"
        )
    if min(pred.shape[:2]) < SSIM_WINDOW:
        raise ValueError(f"SSIM needs images of at least {SSIM_WINDOW} px a side")
    x, y = (t.double().permute(2, 0, 1)[:, None] for t in (pred, target))  # (C,1,H,W)
    # The five local sums in one batch, the window as a row then a column (22 taps): torch's
    # float64 convolution unfolds the input once per tap, and the 11 x 11 window's 121 taps
    # would spend most of the evaluation's time faulting in fresh memory.
    g = gaussian_kernel()
    sums = F.conv2d(
        F.conv2d(torch.cat([x, y, x * x, y * y, x * y]), g[None, None, None]),
        g[None, None, :, None],
    )
    mx, my, xx, yy, xy = sums.chunk(5)
    vx, vy, cxy = xx - mx**2, yy - my**2, xy - mx * my
    ssim_map = (
        (2 * mx * my + SSIM_C1)
        * (2 * cxy + SSIM_C2)
        / ((mx**2 + my**2 + SSIM_C1) * (vx + vy + SSIM_C2))
    )
    return ssim_map[:, 0]
