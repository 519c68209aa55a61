"""Test-frame metrics of an avatar at several levels of detail and precisions."""

from __future__ import annotations

import statistics
from dataclasses import dataclass

import numpy as np
import torch

from ..avatar.runtime import AvatarRuntime
from .metrics import l1, psnr, ssim
from .render import driving_codes, render_frame

LODS = (0.0, 0.25, 0.5, 0.75, 1.0)
PRECISIONS = ("fp32", "fp16")


@dataclass
class LodResult:
    lod: float
    precision: str
    resolution: int  # UV resolution S
    gaussians: int
    l1: float  # means over the test frames, each over the whole (masked) frame
    psnr: float
    ssim: float
    st_lpips: float
    decode_ms: float  # medians over the test frames
    splat_ms: float
    # over the tracked head without its neck (the dataset's `head`), where no mask reaches
    psnr_head: float = float("nan")
    ssim_head: float = float("nan")
    st_lpips_head: float = float("nan")
    psnr_face: float = float("nan")  # over the face (flame.regions): where hair rarely falls
    needles: float = 0.0  # the share of Gaussians with an axis ratio above 10 (render.py)
    rods: float = 0.0  # the share with a longest axis over 3 times the middle one (render.py)
    black: float = 0.0  # the share drawn black (render.black_share)

    @property
    def render_ms(self) -> float:
        return self.decode_ms + self.splat_ms


def evaluate_lods(
    runtime: AvatarRuntime,
    frames: list[dict],
    size: tuple[int, int],
    background,
    perceptual,
    lods=LODS,
    precisions=PRECISIONS,
    on_frame=None,
    cut: bool = False,
) -> list[LodResult]:
    """Render every frame (dataset items) at every (lod, precision), with `cut` cut to the
    item's `region` as the truth is; on_frame(lod, precision, index, rgb) sees each image.
    Times exclude a first, untimed decode that fills the runtime's per-resolution cache."""
    results = []
    for precision in precisions:
        for lod in lods:
            first = frames[0]
            runtime.decode(lod, precision=precision, **driving_codes(first["codes"]))
            scores, decode, splat, needles, rods, black = [], [], [], [], [], []
            for i, item in enumerate(frames):
                out = render_frame(
                    runtime, lod, item["codes"], item["K"], item["w2c"], size, background, precision
                )
                rgb = cut_to_region(out.rgb, item["region"], background) if cut else out.rgb
                if on_frame is not None:
                    on_frame(lod, precision, i, rgb)
                scores.append(
                    _scores(rgb, item["image"], item.get("head"), item.get("face"), perceptual)
                )
                decode.append(out.decode_ms)
                splat.append(out.splat_ms)
                needles.append(out.needles)
                rods.append(out.rods)
                black.append(out.black)
            mean = [float(x) for x in np.nanmean(np.array(scores, np.float64), axis=0)]
            results.append(
                LodResult(
                    lod,
                    precision,
                    runtime.resolution(lod),
                    out.gaussians,
                    *mean[:4],
                    statistics.median(decode),
                    statistics.median(splat),
                    *mean[4:],
                    needles=float(np.mean(needles)),
                    rods=float(np.mean(rods)),
                    black=float(np.mean(black)),
                )
            )
    return results


def cut_to_region(rgb: np.ndarray, region: np.ndarray, background) -> np.ndarray:
    """The render where `region` (H,W) holds, the background elsewhere (train `cut`)."""
    bg = np.asarray(background, np.float32)
    return bg + region[..., None] * (rgb - bg)


def _scores(rgb: np.ndarray, target: np.ndarray, head, face, perceptual) -> tuple[float, ...]:
    """L1, PSNR, SSIM, ST-LPIPS over the frame, then PSNR, SSIM and ST-LPIPS over `head`, then
    PSNR over `face` (NaN for a region that is absent or empty). The head's ST-LPIPS compares
    the truth with the render pasted into it there, so what lies outside the head does not
    count."""
    pred, gt = torch.from_numpy(np.clip(rgb, 0, 1)), torch.from_numpy(target)
    whole = (l1(pred, gt), psnr(pred, gt), ssim(pred, gt), _perceptual(perceptual, pred, gt))
    inside = (np.nan, np.nan, np.nan)
    if head is not None and head.any():
        region = torch.from_numpy(np.asarray(head, np.float32))
        pasted = region[..., None] * pred + (1 - region[..., None]) * gt
        inside = (
            psnr(pred, gt, region),
            ssim(pred, gt, region),
            _perceptual(perceptual, pasted, gt),
        )
    in_face = np.nan
    if face is not None and face.any():
        in_face = psnr(pred, gt, torch.from_numpy(np.asarray(face, np.float32)))
    return (*whole, *inside, in_face)


def _perceptual(perceptual, pred: torch.Tensor, gt: torch.Tensor) -> float:
    with torch.no_grad():
        return float(perceptual(pred.permute(2, 0, 1)[None], gt.permute(2, 0, 1)[None])[0])
