"""Level of detail -> UV resolution (paper eq. 3) and the feature-field blend weights (eq. 5)."""

from __future__ import annotations

import math
import warnings

import numpy as np


def resolution_for_lod(lod: float, s_max: int = 256, s_min: int = 64) -> tuple[float, int]:
    """(l clamped to [0, 1], S = S_max - l (S_max - S_min) rounded half up).

    l = 0 is the most detailed level. A value outside [0, 1] is clamped with a warning."""
    lod = float(lod)
    if math.isnan(lod):
        raise ValueError("the level of detail is NaN")
    clamped = min(max(lod, 0.0), 1.0)
    if clamped != lod:
        warnings.warn(f"level of detail {lod} outside [0, 1]; using {clamped}", stacklevel=2)
    return clamped, int(math.floor(s_max - clamped * (s_max - s_min) + 0.5))


def blend_weights(levels, size: float, tau: float) -> np.ndarray:
    """w_i = exp(-|ln S_i - ln S| / tau) / sum_j exp(-|ln S_j - ln S| / tau), float64."""
    logits = -np.abs(np.log(np.asarray(levels, dtype=np.float64)) - math.log(size)) / tau
    w = np.exp(logits - logits.max(initial=0.0))
    return w / w.sum()
