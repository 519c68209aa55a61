"""Drive LOD by Camera Distance, for every selected avatar (archhead_blender.lod_driver
installs the driver)."""

from __future__ import annotations

import bpy

from archhead_blender.avatar_objects import active_avatar, selected_avatars
from archhead_blender.lod_driver import drive_lod_by_distance


class ARCHHEAD_OT_drive_lod(bpy.types.Operator):
    """Drive the selected avatars' level of detail by the scene camera's distance to each head"""

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

    mode: bpy.props.EnumProperty(
        name="By",
        default="DISTANCE",
        items=(
            ("DISTANCE", "Distance", "The camera's distance to the head"),
            (
                "SCREEN",
                "Screen size",
                "The head's size in the image (its distance through the camera's lens): the "
                "detail falls as the head shrinks, the same Gaussians per pixel from near to "
                "far when far is 4x near",
            ),
        ),
    )

    @classmethod
    def poll(cls, context):
        return context.scene.camera is not None and active_avatar(context) is not None

    def execute(self, context):
        avatars = selected_avatars(context)
        try:
            for obj in avatars:
                drive_lod_by_distance(obj, context.scene.camera, self.near, self.far, self.mode)
        except ValueError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        if len(avatars) > 1:
            self.report({"INFO"}, f"{len(avatars)} avatars driven by the camera")
        return {"FINISHED"}

    def invoke(self, context, event):
        return context.window_manager.invoke_props_dialog(self)
