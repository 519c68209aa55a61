"""Operators: thin wrappers around the functions in this package's other modules."""

import bpy

from . import import_sequence

_CLASSES = (import_sequence.ARCHHEAD_OT_import_sequence,)


def _menu_import(self, context):
    self.layout.operator(import_sequence.ARCHHEAD_OT_import_sequence.bl_idname,
                         text="Tracked FLAME sequence (ArchHead)")


def register():
    for cls in _CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.TOPBAR_MT_file_import.append(_menu_import)


def unregister():
    bpy.types.TOPBAR_MT_file_import.remove(_menu_import)
    for cls in reversed(_CLASSES):
        bpy.utils.unregister_class(cls)
