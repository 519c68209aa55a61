"""Export the avatar's Gaussians as standard 3DGS PLY files: the current frame or a range.

What is written is what the point instances show, without the Gaussians below 1/255 opacity,
with every SH band the avatar has (decoded for the export where the display shows the DC
term), in display-space colour as 3DGS readers blend it (a linear avatar's converted:
splat/colour_space.py). Space: FLAME (metres, y up, as the avatar was trained and as
the tracking's cameras see it) or Blender's world (the avatar object's transform applied,
z up, with the view-dependent SH bands rotated along).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from archhead_addon.export.ply import write_ply
from archhead_addon.export.transform import transform_frame
from archhead_addon.splat.colour_space import sh_as_display

from .avatar_session import session
from .handlers import frame_to_show


def frame_path(path: Path, frame: int) -> Path:
    """`name_####.ply` style: '#' runs become the zero-padded frame, else _NNNN is added."""
    stem = path.stem
    if "#" in stem:
        width = stem.count("#")
        head, _, tail = stem.partition("#" * width)
        return path.with_name(f"{head}{frame:0{width}d}{tail.replace('#', '')}{path.suffix}")
    return path.with_name(f"{stem}_{frame:04d}{path.suffix}")


def export_ply(context, obj, path, frames=None, space: str = "FLAME") -> list[Path]:
    """Write one PLY per frame (None: the current frame, to `path` itself)."""
    scene = context.scene
    path = Path(path)
    start = scene.frame_current
    targets = [(start, path)] if frames is None else [(f, frame_path(path, f)) for f in frames]
    written = []
    colour_space = session(obj).runtime.config.colour_space
    try:
        for frame, target in targets:
            if frame != scene.frame_current:
                scene.frame_set(frame)
            depsgraph = context.evaluated_depsgraph_get()
            _, splat = frame_to_show(obj, scene, depsgraph, full_colour=True)
            if colour_space == "linear":  # PLY readers blend display values (3DGS)
                splat = replace(splat, sh=sh_as_display(splat.sh))
            if space == "WORLD":
                splat = transform_frame(np.array(obj.evaluated_get(depsgraph).matrix_world), splat)
            write_ply(target, **splat.arrays())
            written.append(target)
    finally:
        if scene.frame_current != start:
            scene.frame_set(start)
    return written
