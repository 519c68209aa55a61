"""Load Avatar: attach a checkpoint to every selected head (archhead_blender.avatar_objects);
a crowd of heads shares one decoder of it."""

from __future__ import annotations

import bpy
from bpy_extras.io_utils import ImportHelper

from archhead_addon.io.errors import InputError
from archhead_blender.avatar_objects import head_of, load_avatar, selected_heads


class ARCHHEAD_OT_load_avatar(bpy.types.Operator, ImportHelper):
    """Attach a trained avatar checkpoint to the selected imported heads"""

    bl_idname = "archhead.load_avatar"
    bl_label = "Load Avatar"
    bl_options = {"REGISTER", "UNDO"}

    filename_ext = ".npz"
    filter_glob: bpy.props.StringProperty(default="*.npz", options={"HIDDEN"})

    @classmethod
    def poll(cls, context):
        return head_of(context.active_object) is not None

    def execute(self, context):
        loaded, failed = [], []
        for head in selected_heads(context):  # a head that fails is left as it was
            try:
                obj, warnings = load_avatar(context, head, self.filepath)
            except (InputError, OSError, ValueError) as exc:
                failed.append(f"{head.name}: {exc}")
                continue
            for warning in warnings:
                self.report({"WARNING"}, warning)
            loaded.append(obj)
        for message in failed:
            self.report({"ERROR"}, message)
        if not loaded:
            return {"CANCELLED"}
        if len(loaded) == 1:
            obj = loaded[0]
            self.report({"INFO"}, f"{obj.name}: {len(obj.data.vertices):,} Gaussians")
        else:
            self.report({"INFO"}, f"Loaded the avatar on {len(loaded)} heads")
        return {"FINISHED"}
