"""The point-instance attributes of a decoded frame (what Blender's point object carries).

Colours: Blender's attributes are scene-linear and its "Standard" view transform encodes the
blended result to sRGB. A linear avatar's colours are that already; a display-space one's
(3DGS's, older checkpoints) are linearised, which matches where one Gaussian covers a pixel
but not where several blend (splat/colour_space.py). An Emission shader of strength 1 then
reproduces them. `colour` is the SH DC term (view-independent); `colour_view`, when asked,
is the full SH colour seen from a camera centre, with alpha 1 so the material can tell it
from an absent attribute (alpha 0).
"""

from __future__ import annotations

import numpy as np

from ..splat.colour_space import srgb_to_linear
from ..splat.frame import SplatFrame
from ..splat.sh import degree_from_coeffs, sh_to_rgb_numpy
from .gaussians import SH_C0


def _rgba(rgb: np.ndarray, colour_space: str) -> np.ndarray:
    out = np.ones((len(rgb), 4), np.float32)
    out[:, :3] = rgb if colour_space == "linear" else srgb_to_linear(rgb)
    return out


def point_attributes(
    frame: SplatFrame, view_from=None, colour_space: str = "linear"
) -> dict[str, np.ndarray]:
    """Arrays per point: position (N,3), scale (N,3) standard deviations, rotation (N,4)
    w,x,y,z, opacity (N,), colour (N,4) and, with `view_from` (a camera centre in the
    frame's FLAME space) and SH above degree 0, colour_view (N,4). `colour_space`: the
    avatar's (AvatarConfig.colour_space)."""
    out = {
        "position": frame.means,
        "scale": np.exp(frame.log_scales, dtype=np.float32),
        "rotation": frame.quats,
        "opacity": (1.0 / (1.0 + np.exp(-frame.opacity_logits))).astype(np.float32),
        "colour": _rgba(np.maximum(0.5 + SH_C0 * frame.sh[:, 0], 0.0), colour_space),
    }
    if view_from is not None and frame.sh.shape[1] > 1:  # one coefficient: `colour` is all
        dirs = frame.means - np.asarray(view_from, np.float32)
        rgb = sh_to_rgb_numpy(degree_from_coeffs(frame.sh.shape[1]), dirs, frame.sh)
        out["colour_view"] = _rgba(rgb, colour_space)
    return out
