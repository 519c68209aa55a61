"""Export the avatar's Gaussians as standard 3DGS PLY files: the current frame or a range.

What is written is what the point instances show (the same cache entry), without the
Gaussians below 1/255 opacity. Space: FLAME (metres, y up, as the avatar was trained and as
the tracking's cameras see it) or Blender's world (the avatar object's transform applied,
z up, with the view-dependent SH bands rotated along).
"""

from __future__ import annotations

from pathlib import Path

import bpy
import numpy as np
from bpy_extras.io_utils import ExportHelper

from ..archhead_addon.avatar.frame_selection import parse_frames
from ..archhead_addon.export.ply import write_ply
from ..archhead_addon.export.transform import transform_gaussians
from ..archhead_addon.io.errors import InputError
from .avatar_load import active_avatar
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
    try:
        for frame, target in targets:
            if frame != scene.frame_current:
                scene.frame_set(frame)
            depsgraph = context.evaluated_depsgraph_get()
            _, splat = frame_to_show(obj, scene, depsgraph)
            arrays = (splat.means, splat.log_scales, splat.quats, splat.sh)
            if space == "WORLD":
                world = np.array(obj.evaluated_get(depsgraph).matrix_world)
                arrays = transform_gaussians(world, *arrays)
            means, log_scales, quats, sh = arrays
            write_ply(target, means, log_scales, quats, splat.opacity_logits, sh)
            written.append(target)
    finally:
        if scene.frame_current != start:
            scene.frame_set(start)
    return written


class ARCHHEAD_OT_export_ply(bpy.types.Operator, ExportHelper):
    """Export the avatar's Gaussians as 3DGS PLY files (current frame or a range)"""

    bl_idname = "archhead.export_ply"
    bl_label = "Export Gaussians (PLY)"

    filename_ext = ".ply"
    filter_glob: bpy.props.StringProperty(default="*.ply", options={"HIDDEN"})
    frames: bpy.props.EnumProperty(
        name="Frames", default="CURRENT",
        items=(("CURRENT", "Current frame", "One file"),
               ("SCENE", "Scene range", "One file per frame, name_####.ply"),
               ("CUSTOM", "Custom", "Frames like 1-20, 1-20:5 or 3,7")))
    custom_frames: bpy.props.StringProperty(name="Frame list", default="1-10")
    space: bpy.props.EnumProperty(
        name="Space", default="FLAME",
        items=(("FLAME", "FLAME", "Metres, y up: the tracking's space (its cameras fit)"),
               ("WORLD", "Blender world", "With the avatar object's transform, z up")))

    @classmethod
    def poll(cls, context):
        return active_avatar(context) is not None

    def execute(self, context):
        scene = context.scene
        try:
            frames = None
            if self.frames == "SCENE":
                frames = range(scene.frame_start, scene.frame_end + 1)
            elif self.frames == "CUSTOM":
                frames = parse_frames(self.custom_frames)
            written = export_ply(context, active_avatar(context), self.filepath, frames,
                                 self.space)
        except (InputError, OSError, ValueError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"Wrote {len(written)} PLY file(s), {written[0].name} ...")
        return {"FINISHED"}
