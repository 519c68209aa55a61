"""The N-panel (View3D sidebar, tab "ArchHead"): UI only. Preferences are registered with the
rest of the Blender side (archhead_blender)."""

import bpy

from . import main_panel

_CLASSES = (main_panel.ARCHHEAD_PT_main,)


def register():
    for cls in _CLASSES:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(_CLASSES):
        bpy.utils.unregister_class(cls)
