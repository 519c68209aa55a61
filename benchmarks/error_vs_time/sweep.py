"""What every level of detail costs and loses: test-frame error (fp32, fp16, through
`evaluate.lods`), decode time, the splat kernel's time at 512 x 512, and the image change
between neighbouring levels."""

from __future__ import annotations

import statistics
from dataclasses import dataclass

import numpy as np

from archhead_addon.avatar.runtime import AvatarRuntime
from archhead_addon.evaluate.lods import LodResult, evaluate_lods
from archhead_addon.evaluate.render import driving_codes, render_frame
from archhead_addon.timing import Stopwatch

KERNEL_SIZE = 512


@dataclass
class LodRow:
    """One level of detail: the fp32 and fp16 evaluations, decode and kernel times."""

    fp32: LodResult
    fp16: LodResult
    decode_ms: dict[str, float]  # precision -> median over the test frames (decode_ms())
    kernel_ms: float  # SH colour + splat of the LOD's Gaussians at KERNEL_SIZE²

    @property
    def lod(self) -> float:
        return self.fp32.lod

    @property
    def frame_ms(self) -> float:
        """fp32 decode + kernel at 512²: one frame's run time."""
        return self.decode_ms["fp32"] + self.kernel_ms


def lod_steps(step: float) -> list[float]:
    return [round(i * step, 6) for i in range(round(1 / step) + 1)]


def measure_lods(
    runtime: AvatarRuntime,
    frames: list[dict],
    size: tuple[int, int],
    background,
    perceptual,
    lods: list[float],
    repeats: int = 3,
    cut: bool = False,
) -> tuple[list[LodRow], dict[float, np.ndarray]]:
    """The rows per LOD and the first test frame's fp32 image per LOD (`cut`: the renders
    cut to the region, as `evaluate` scores a run that trained so)."""
    first: dict[float, np.ndarray] = {}

    def keep_first(lod, precision, index, rgb):
        if index == 0 and precision == "fp32":
            first[lod] = rgb

    results = evaluate_lods(
        runtime, frames, size, background, perceptual, lods, ("fp32", "fp16"), keep_first, cut
    )
    by_key = {(r.lod, r.precision): r for r in results}
    return [
        LodRow(
            by_key[lod, "fp32"],
            by_key[lod, "fp16"],
            {p: decode_ms(runtime, frames, lod, p) for p in ("fp32", "fp16")},
            kernel_ms(runtime, frames[0], size, background, lod, repeats),
        )
        for lod in lods
    ], first


def decode_ms(runtime: AvatarRuntime, frames: list[dict], lod: float, precision: str) -> float:
    """Median milliseconds of decoding the frames one after another, as Blender plays them
    (the evaluation's own times have a metric's work between decodes, and were uneven from
    one level to the next)."""
    runtime.decode(lod, precision=precision, **driving_codes(frames[0]["codes"]))  # per-S tables
    times = []
    for item in frames:
        watch = Stopwatch()
        runtime.decode(lod, precision=precision, **driving_codes(item["codes"]))
        times.append(1e3 * watch.seconds)
    return statistics.median(times)


def kernel_ms(
    runtime: AvatarRuntime, item: dict, size: tuple[int, int], background, lod: float, repeats: int
) -> float:
    """Median splat milliseconds at KERNEL_SIZE² of the frame's Gaussians, its camera's
    intrinsics scaled up to that size."""
    K = np.diag([KERNEL_SIZE / size[1], KERNEL_SIZE / size[0], 1.0]) @ item["K"]
    times = [
        render_frame(
            runtime, lod, item["codes"], K, item["w2c"], (KERNEL_SIZE, KERNEL_SIZE), background
        ).splat_ms
        for _ in range(repeats)
    ]
    return statistics.median(times)


def image_change(a: np.ndarray, b: np.ndarray) -> float:
    """Mean absolute difference in 8-bit levels (0 .. 255)."""
    return 255.0 * float(np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64)).mean())


def smoothness(images: dict[float, np.ndarray]) -> list[tuple[float, float, float]]:
    """(l, next l, image change) for every pair of neighbouring levels."""
    lods = sorted(images)
    return [
        (a, b, image_change(images[a], images[b])) for a, b in zip(lods, lods[1:], strict=False)
    ]
