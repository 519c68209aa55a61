"""Drive LOD by Camera Distance (archhead_blender.lod_driver installs the driver)."""

from __future__ import annotations

import bpy

from archhead_blender.avatar_objects import active_avatar
from archhead_blender.lod_driver import drive_lod_by_distance


class ARCHHEAD_OT_drive_lod(bpy.types.Operator):
    """Drive the avatar's level of detail by the scene camera's distance to the head"""

    bl_idname = "archhead.drive_lod"
    bl_label = "Drive LOD by Camera Distance"
    bl_options = {"REGISTER", "UNDO"}

    near: bpy.props.FloatProperty(
        name="Near",
        min=0.0,
        default=0.5,
        subtype="DISTANCE",
        description="At or closer than this: LOD 0 (most detail)",
    )
    far: bpy.props.FloatProperty(
        name="Far",
        min=0.0,
        default=3.0,
        subtype="DISTANCE",
        description="At or beyond this: LOD 1 (least detail)",
    )

    @classmethod
    def poll(cls, context):
        return context.scene.camera is not None and active_avatar(context) is not None

    def execute(self, context):
        try:
            drive_lod_by_distance(active_avatar(context), context.scene.camera, self.near, self.far)
        except ValueError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        return {"FINISHED"}

    def invoke(self, context, event):
        return context.window_manager.invoke_props_dialog(self)
