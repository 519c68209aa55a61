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
    l1: float
    psnr: float
    ssim: float
    st_lpips: float
    decode_ms: float  # medians over the test frames
    splat_ms: float

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
) -> list[LodResult]:
    """Render every frame (dataset items) at every (lod, precision); on_frame(lod, precision,
    index, rgb) sees each image. Times exclude a first, untimed decode that fills the
    runtime's per-resolution cache."""
    results = []
    for precision in precisions:
        for lod in lods:
            first = frames[0]
            runtime.decode(lod, precision=precision, **driving_codes(first["codes"]))
            scores, decode, splat = [], [], []
            for i, item in enumerate(frames):
                out = render_frame(
                    runtime, lod, item["codes"], item["K"], item["w2c"], size, background, precision
                )
                if on_frame is not None:
                    on_frame(lod, precision, i, out.rgb)
                scores.append(_scores(out.rgb, item["image"], perceptual))
                decode.append(out.decode_ms)
                splat.append(out.splat_ms)
            mean = np.mean(scores, axis=0)
            results.append(
                LodResult(
                    lod,
                    precision,
                    runtime.resolution(lod),
                    out.gaussians,
                    *map(float, mean),
                    statistics.median(decode),
                    statistics.median(splat),
                )
            )
    return results


def _scores(rgb: np.ndarray, target: np.ndarray, perceptual) -> tuple[float, ...]:
    pred, gt = torch.from_numpy(np.clip(rgb, 0, 1)), torch.from_numpy(target)
    with torch.no_grad():
        dist = float(perceptual(pred.permute(2, 0, 1)[None], gt.permute(2, 0, 1)[None])[0])
    return l1(pred, gt), psnr(pred, gt), ssim(pred, gt), dist
