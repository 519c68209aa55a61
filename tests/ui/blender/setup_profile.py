"""After `blender --command extension install-file -e`: the add-on is enabled in a fresh
window of the clean profile, its preferences take the Backend Python (argv), and they are
saved, as a user would in Edit > Preferences."""

import sys
from pathlib import Path

import bpy

sys.path.insert(0, str(Path(__file__).resolve().parent))
from ui_driver import check, run_steps, script_args  # noqa: E402

ADDON = "bl_ext.user_default.archhead"


def enabled(ui):
    check(ADDON in bpy.context.preferences.addons, f"{ADDON} not enabled after install")
    check(hasattr(bpy.ops.archhead, "import_sequence"), "operators not registered")
    ui.data["addons"] = [a.module for a in bpy.context.preferences.addons]


def preferences(ui):
    prefs = bpy.context.preferences.addons[ADDON].preferences
    prefs.backend_python = script_args()[0]
    bpy.context.preferences.view.show_splash = False  # the tests' later windows start bare
    with ui.context(None):
        bpy.ops.wm.save_userpref()
    # saved once: later windows (an add-on disabled and enabled drops its preferences)
    # must not write theirs back when they quit
    bpy.context.preferences.use_preferences_save = False
    with ui.context(None):
        bpy.ops.wm.save_userpref()
    check(Path(bpy.utils.resource_path("USER"), "config", "userpref.blend").exists(), "no prefs")


def panel(ui):
    yield from ui.show_sidebar()
    ui.screenshot("empty_scene_panel")


run_steps([("add-on enabled", enabled), ("preferences saved", preferences), ("panel", panel)])
