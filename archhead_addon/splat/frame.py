"""The one Gaussian container: `SplatFrame`, its fields named and in the 3DGS PLY's order
(means, log_scales, quats, opacity_logits, sh), the order of the decoder's output
(`avatar.gaussians.Gaussians`) and of the C kernel's ABI.

Everything that hands Gaussians on (decode cache, point instances, PLY, transforms, exact
renders, the kernel and its torch wrapper, the test scenes and references) passes a
SplatFrame and reads its fields by name, never by position. gsplat's positional order
(means, quats, log_scales, ...) exists only in the signatures of the gsplat-compatible entry
points, `rendering.rasterization` and `kernel.render`, and `from_gsplat_order` is the one
place where it is turned into a SplatFrame.

numpy only (Blender uses it); the fields may hold torch tensors where a torch function
takes a frame (`rendering.rasterize_frame`, `reference`), see `SplatFrame.map`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields

import numpy as np

MIN_OPACITY = 1.0 / 255.0  # 3DGS skips samples below this alpha; such Gaussians are left out
_LOGIT_MIN = float(np.log(MIN_OPACITY / (1.0 - MIN_OPACITY)))


@dataclass
class SplatFrame:
    """One frame's Gaussians in 3DGS storage conventions (float32 on the numpy side)."""

    means: np.ndarray  # (N,3)
    log_scales: np.ndarray  # (N,3) natural log of the axis scales
    quats: np.ndarray  # (N,4) w, x, y, z
    opacity_logits: np.ndarray  # (N,) opacity = sigmoid(logit)
    # (N,K,3) SH coefficients, DC first, K = (degree + 1)^2; or (N,3) RGB already evaluated
    # (what the kernel draws; the test scenes' colours)
    sh: np.ndarray
    resolution: int = 0  # the UV resolution S it was decoded at (0: not decoded)

    @classmethod
    def from_gaussians(cls, g) -> SplatFrame:
        """The visible Gaussians (opacity at least 1/255) of a decoder output (or anything
        with these field names), as contiguous float32 numpy arrays."""
        keep = np.asarray(g.opacity_logits) >= _LOGIT_MIN
        return cls(
            **{
                name: np.ascontiguousarray(np.asarray(getattr(g, name))[keep], np.float32)
                for name in FIELDS
            },
            resolution=int(g.resolution),
        )

    def __len__(self) -> int:
        return len(self.means)

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in self.arrays().values())

    def arrays(self) -> dict:
        """The arrays by field name, in field order (`write_ply(path, **frame.arrays())`)."""
        return {name: getattr(self, name) for name in FIELDS}

    def map(self, fn: Callable) -> SplatFrame:
        """A frame of fn(array) for every field (e.g. torch tensors that require grad)."""
        return type(self)(
            **{name: fn(a) for name, a in self.arrays().items()}, resolution=self.resolution
        )

    def checked(self) -> SplatFrame:
        """Contiguous float32 copies (or views) with consistent shapes, every entry finite:
        the kernel's input. A bad array raises ValueError naming the field."""
        means = check_array("means", self.means, (-1, 3))
        n = means.shape[0]
        sh = np.asarray(self.sh)
        return type(self)(
            means=means,
            log_scales=check_array("log_scales", self.log_scales, (n, 3)),
            quats=check_array("quats", self.quats, (n, 4)),
            opacity_logits=check_array("opacity_logits", self.opacity_logits, (n,)),
            sh=check_array("sh", sh, (n, 3) if sh.ndim == 2 else (n, -1, 3)),
            resolution=self.resolution,
        )

    @classmethod
    def concatenate(cls, frames: list[SplatFrame]) -> SplatFrame:
        """Several frames as one (a scene's avatars in one space); resolution of the first."""
        arrays = [f.arrays() for f in frames]
        return cls(
            **{name: np.concatenate([a[name] for a in arrays]) for name in FIELDS},
            resolution=frames[0].resolution,
        )


FIELDS = tuple(f.name for f in fields(SplatFrame) if f.name != "resolution")


def from_gsplat_order(means, quats, log_scales, opacity_logits, colors) -> SplatFrame:
    """The arguments of a gsplat-style call (`rasterization`, `kernel.render`: quats before
    log_scales, `colors` for SH or RGB) as a SplatFrame: the one place the two orders meet."""
    return SplatFrame(
        means=means, log_scales=log_scales, quats=quats, opacity_logits=opacity_logits, sh=colors
    )


def check_array(name: str, x, shape: tuple, dtype=np.float32) -> np.ndarray:
    """C-contiguous float32 (or dtype) copy/view of x with the given shape (-1: any); finite."""
    a = np.ascontiguousarray(x, dtype=dtype)
    if a.ndim != len(shape) or any(s not in (-1, d) for s, d in zip(shape, a.shape, strict=True)):
        want = "(" + ", ".join("N" if s == -1 else str(s) for s in shape) + ")"
        raise ValueError(f"{name} must have shape {want}, got {tuple(a.shape)}")
    bad = a.size - int(np.count_nonzero(np.isfinite(a)))
    if bad:
        raise ValueError(f"{name} contains {bad} non-finite value(s) (NaN, Inf, or beyond float32)")
    return a
