"""Load Avatar: attach a checkpoint to the selected head (archhead_blender.avatar_objects)."""

from __future__ import annotations

import bpy
from bpy_extras.io_utils import ImportHelper

from archhead_addon.io.errors import InputError
from archhead_blender.avatar_objects import head_of, load_avatar


class ARCHHEAD_OT_load_avatar(bpy.types.Operator, ImportHelper):
    """Attach a trained avatar checkpoint to the selected imported head"""

    bl_idname = "archhead.load_avatar"
    bl_label = "Load Avatar"
    bl_options = {"REGISTER", "UNDO"}

    filename_ext = ".npz"
    filter_glob: bpy.props.StringProperty(default="*.npz", options={"HIDDEN"})

    @classmethod
    def poll(cls, context):
        return head_of(context.active_object) is not None

    def execute(self, context):
        head = head_of(context.active_object)
        try:
            obj, warnings = load_avatar(context, head, self.filepath)
        except (InputError, OSError, ValueError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        for warning in warnings:
            self.report({"WARNING"}, warning)
        self.report({"INFO"}, f"{obj.name}: {len(obj.data.vertices):,} Gaussians")
        return {"FINISHED"}
