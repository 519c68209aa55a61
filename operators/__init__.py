"""Operators: thin classes around archhead_blender's functions (the work and the state live
there; scripts call those functions directly through archhead_blender.api)."""

import bpy

from . import (
    avatar_decode,
    avatar_load,
    import_sequence,
    lod,
    ply_export,
    track_operator,
    train_operator,
    video_avatar_operator,
)

_CLASSES = (
    import_sequence.ARCHHEAD_OT_import_sequence,
    avatar_load.ARCHHEAD_OT_load_avatar,
    avatar_decode.ARCHHEAD_OT_decode_avatar,
    avatar_decode.ARCHHEAD_OT_cancel_decode,
    lod.ARCHHEAD_OT_drive_lod,
    ply_export.ARCHHEAD_OT_export_ply,
    train_operator.ARCHHEAD_OT_train_avatar,
    train_operator.ARCHHEAD_OT_cancel_training,
    track_operator.ARCHHEAD_OT_track_video,
    track_operator.ARCHHEAD_OT_cancel_tracking,
    video_avatar_operator.ARCHHEAD_OT_avatar_from_video,
    video_avatar_operator.ARCHHEAD_OT_cancel_video_avatar,
)


def _menu_import(self, context):
    self.layout.operator(
        import_sequence.ARCHHEAD_OT_import_sequence.bl_idname,
        text="Tracked FLAME sequence (ArchHead)",
    )


def _menu_export(self, context):
    self.layout.operator(
        ply_export.ARCHHEAD_OT_export_ply.bl_idname, text="ArchHead Gaussians (.ply)"
    )


def register():
    for cls in _CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.TOPBAR_MT_file_import.append(_menu_import)
    bpy.types.TOPBAR_MT_file_export.append(_menu_export)


def unregister():
    bpy.types.TOPBAR_MT_file_export.remove(_menu_export)
    bpy.types.TOPBAR_MT_file_import.remove(_menu_import)
    for cls in reversed(_CLASSES):
        bpy.utils.unregister_class(cls)
