"""Frames of a trained avatar through the numpy runtime and the C++ splat kernel: the path
Blender uses, timed per part (decode, then SH colour + splat), blended in the avatar's colour
space (splat/colour_space.py)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..avatar.config import ROD_RATIO
from ..avatar.culling import ViewFrustum
from ..avatar.runtime import AvatarRuntime
from ..camera import affine_inverse
from ..splat import kernel
from ..splat.colour_space import display_background, linear_to_srgb
from ..splat.sh import degree_from_coeffs, sh_to_rgb_numpy
from ..timing import Stopwatch

DRIVING_CODES = ("expr", "jaw", "neck", "eyes", "rotation", "translation")


def driving_codes(codes: dict) -> dict:
    """The codes that drive a decode (DRIVING_CODES present in `codes`; shape is baked in)."""
    return {k: codes[k] for k in DRIVING_CODES if k in codes}


NEEDLE_RATIO = 10.0  # a Gaussian whose longest axis is this many times its shortest


@dataclass
class RenderedFrame:
    rgb: np.ndarray  # (H,W,3) float32 over the background
    gaussians: int
    decode_ms: float
    splat_ms: float  # SH to RGB and the splat kernel
    needles: float  # the share of Gaussians with an axis ratio above NEEDLE_RATIO
    rods: float  # the share whose longest axis is more than ROD_RATIO times the middle one
    black: float  # the share drawn black: colour 0 in every channel (`black_share`)

    @property
    def total_ms(self) -> float:
        return self.decode_ms + self.splat_ms


def render_frame(
    runtime: AvatarRuntime,
    lod: float,
    codes: dict,
    K,
    w2c,
    size: tuple[int, int],
    background,
    precision: str = "fp32",
    num_threads: int = 0,
    view: ViewFrustum | None = None,
) -> RenderedFrame:
    """One frame at level `lod`: codes (DRIVING_CODES, others ignored), K (3,3) and OpenCV
    w2c (4,4) for an image of size (H, W); `view` culls before decoding (culling.py)."""
    watch = Stopwatch()
    g = runtime.decode(lod, precision=precision, view=view, **driving_codes(codes))
    decode_ms = 1e3 * watch.seconds
    watch = Stopwatch()
    space = runtime.config.colour_space
    sh = np.asarray(g.sh, np.float32)
    centre = affine_inverse(w2c)[:3, 3]
    colours = sh_to_rgb_numpy(degree_from_coeffs(sh.shape[1]), g.means - centre, sh)
    settings = kernel.RasterSettings(
        viewmat=np.asarray(w2c, np.float64),
        K=np.asarray(K, np.float64),
        width=size[1],
        height=size[0],
        background=tuple(map(float, display_background(background, space))),
        num_threads=num_threads,
    )
    raster = kernel.render(g.means, g.quats, g.log_scales, g.opacity_logits, colours, settings)
    rgb = linear_to_srgb(raster.rgb) if space == "linear" else raster.rgb
    splat_ms = 1e3 * watch.seconds
    return RenderedFrame(
        rgb.astype(np.float32),
        len(g),
        decode_ms,
        splat_ms,
        needle_share(g),
        rod_share(g),
        black_share(colours),
    )


def needle_share(g) -> float:
    """The share of the decoded Gaussians whose axes differ more than NEEDLE_RATIO times: the
    streaks an artist sees as needles."""
    spread = np.ptp(np.asarray(g.log_scales, np.float64), axis=1)
    return float((spread > np.log(NEEDLE_RATIO)).mean()) if len(spread) else 0.0


def rod_share(g) -> float:
    """The share of the decoded Gaussians whose longest axis is more than ROD_RATIO times
    the middle one: rods, drawn as dashes (a thin disc, long in two axes, is not one)."""
    axes = np.sort(np.asarray(g.log_scales, np.float64), axis=1)
    return float((axes[:, 2] - axes[:, 1] > np.log(ROD_RATIO)).mean()) if len(axes) else 0.0


def black_share(colours: np.ndarray) -> float:
    """The share of Gaussians whose colour (N,3), floored at 0 as 3DGS floors it, is 0 in
    every channel: a pupil's, or a colour that training drove below the floor, where the
    floor leaves it no gradient to come back by (docs/quality.md, "Black Gaussians")."""
    return float((colours.max(axis=1) <= 0).mean()) if len(colours) else 0.0
