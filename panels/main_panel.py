"""The ArchHead tab of the 3D view's sidebar."""

import bpy

from .preferences import get_preferences


def active_head(context):
    """The imported head for the active object (the head itself or its armature)."""
    obj = context.active_object
    if obj is None:
        return None
    if "archhead_model_id" in obj:
        return obj
    name = obj.get("archhead_head")
    return bpy.data.objects.get(name) if name else None


class ARCHHEAD_PT_main(bpy.types.Panel):
    bl_label = "ArchHead"
    bl_idname = "ARCHHEAD_PT_main"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "ArchHead"

    def draw(self, context):
        layout = self.layout
        prefs = get_preferences(context)
        model = (prefs.flame_model_path if prefs else "") or "built-in"
        layout.label(text=f"Model: {bpy.path.basename(model) or model}", icon="MESH_MONKEY")
        layout.operator("archhead.import_sequence", icon="IMPORT")
        head = active_head(context)
        if head is None:
            layout.label(text="No imported head selected")
            return
        box = layout.box()
        box.label(text=head.name, icon="OUTLINER_OB_ARMATURE")
        box.label(text=f"Frames: {head.get('archhead_frames', '?')}  "
                       f"fps: {head.get('archhead_source_fps', 0):g}")
        box.label(text=f"Format: {head.get('archhead_format', '?')}")
        box.label(text=f"Expressions: {head.get('archhead_n_expr', 0)}")
