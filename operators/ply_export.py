"""Export Gaussians (PLY): the current frame or a range (archhead_blender.ply_files)."""

from __future__ import annotations

import bpy
from bpy_extras.io_utils import ExportHelper

from archhead_addon.avatar.frame_selection import parse_frames
from archhead_addon.io.errors import InputError
from archhead_blender.avatar_objects import active_avatar
from archhead_blender.ply_files import export_ply


class ARCHHEAD_OT_export_ply(bpy.types.Operator, ExportHelper):
    """Export the avatar's Gaussians as 3DGS PLY files (current frame or a range)"""

    bl_idname = "archhead.export_ply"
    bl_label = "Export Gaussians (PLY)"

    filename_ext = ".ply"
    filter_glob: bpy.props.StringProperty(default="*.ply", options={"HIDDEN"})
    frames: bpy.props.EnumProperty(
        name="Frames",
        default="CURRENT",
        items=(
            ("CURRENT", "Current frame", "One file"),
            ("SCENE", "Scene range", "One file per frame, name_####.ply"),
            ("CUSTOM", "Custom", "Frames like 1-20, 1-20:5 or 3,7"),
        ),
    )
    custom_frames: bpy.props.StringProperty(name="Frame list", default="1-10")
    space: bpy.props.EnumProperty(
        name="Space",
        default="FLAME",
        items=(
            ("FLAME", "FLAME", "Metres, y up: the tracking's space (its cameras fit)"),
            ("WORLD", "Blender world", "With the avatar object's transform, z up"),
        ),
    )

    @classmethod
    def poll(cls, context):
        if active_avatar(context) is not None:
            return True
        # the tooltip of the greyed File > Export entry says why
        cls.poll_message_set("Select an ArchHead avatar, or its head (Load Avatar in the sidebar)")
        return False

    def execute(self, context):
        scene = context.scene
        try:
            frames = None
            if self.frames == "SCENE":
                frames = range(scene.frame_start, scene.frame_end + 1)
            elif self.frames == "CUSTOM":
                frames = parse_frames(self.custom_frames)
            written = export_ply(context, active_avatar(context), self.filepath, frames, self.space)
        except (InputError, OSError, ValueError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"Wrote {len(written)} PLY file(s), {written[0].name} ...")
        return {"FINISHED"}
