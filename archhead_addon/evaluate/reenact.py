"""Cross-identity reenactment: an avatar driven by another sequence's expression, jaw, eye and
head-pose codes (its identity shape is ignored), seen by that sequence's cameras."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..avatar.runtime import AvatarRuntime
from ..io.atomic import atomic_path
from ..sequences import Sequence
from .render import DRIVING_CODES, render_frame


def driver_cameras(driver: Sequence, size: tuple[int, int], fallback) -> tuple:
    """(K (T,3,3), w2c (T,4,4)) for images of size (H, W): the driver's own cameras scaled
    from its image size, or `fallback` (K, w2c) on every frame when it has none."""
    n = len(driver)
    if not driver.has_camera:
        K, w2c = (np.asarray(a, np.float64) for a in fallback)
        return np.tile(K, (n, 1, 1)), np.tile(w2c, (n, 1, 1))
    tracked = driver.image_size or size
    scale = np.diag([size[1] / tracked[1], size[0] / tracked[0], 1.0])
    return scale @ driver.K, driver.w2c


def to_png(path: Path, rgb: np.ndarray) -> None:
    from PIL import Image

    pixels = np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8)
    with atomic_path(path) as tmp:
        Image.fromarray(pixels).save(tmp, format="PNG")


def reenact(
    runtime: AvatarRuntime,
    driver: Sequence,
    out_dir,
    size: tuple[int, int],
    background,
    fallback_camera,
    lod: float = 0.0,
    frames: int | None = None,
    precision: str = "fp32",
) -> list[Path]:
    """Render the first `frames` (all if None) frames of `driver` as OUT/00000.png ..."""
    driver = driver.fit_to_model(runtime.mesh)
    n = len(driver) if frames is None else min(frames, len(driver))
    K, w2c = driver_cameras(driver, size, fallback_camera)
    paths = []
    for t in range(n):
        codes = {k: getattr(driver, k)[t] for k in DRIVING_CODES}
        out = render_frame(runtime, lod, codes, K[t], w2c[t], size, background, precision)
        paths.append(Path(out_dir) / f"{t:05d}.png")
        to_png(paths[-1], out.rgb)
    return paths
