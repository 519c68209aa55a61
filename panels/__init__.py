"""N-panel (View3D sidebar, tab "ArchHead") and add-on preferences."""

import bpy

from . import main_panel, preferences

_CLASSES = (main_panel.ARCHHEAD_PT_main,)


def register_preferences():
    bpy.utils.register_class(preferences.ArchHeadPreferences)


def unregister_preferences():
    bpy.utils.unregister_class(preferences.ArchHeadPreferences)


def register():
    for cls in _CLASSES:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(_CLASSES):
        bpy.utils.unregister_class(cls)
