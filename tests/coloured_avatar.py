"""An avatar of one known colour: a checkpoint whose colour head ignores its input and puts
out the DC coefficients of `rgb` (display values, linearised for a linear avatar), everything
else unchanged. Tests of what
Solid mode shows need a colour no grey could pass for."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from archhead_addon.avatar.checkpoint_format import read_checkpoint, write_checkpoint
from archhead_addon.avatar.gaussians import SH_C0
from archhead_addon.splat.colour_space import srgb_to_linear

SKIN = (0.85, 0.45, 0.25)  # display values


def write_coloured_avatar(source: Path, out: Path, rgb=SKIN) -> Path:
    ckpt = read_checkpoint(source)
    params = dict(ckpt.params)
    weight = params["decoder.heads.colour.out.weight"]
    bias = np.zeros_like(params["decoder.heads.colour.out.bias"])
    rgb = np.asarray(rgb, np.float32)
    if ckpt.config.colour_space == "linear":  # the avatar's colours are linear
        rgb = srgb_to_linear(rgb)
    bias[:3] = (rgb - 0.5) / SH_C0  # the DC rows come first
    params["decoder.heads.colour.out.weight"] = np.zeros_like(weight)
    params["decoder.heads.colour.out.bias"] = bias
    write_checkpoint(out, replace(ckpt, params=params))
    return out
