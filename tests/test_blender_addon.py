"""The extension installs, registers, unregisters and registers again cleanly."""

import bpy
from addon_env import ADDON_MODULE, installed_addon


def _handler_counts():
    return {name: len(getattr(bpy.app.handlers, name)) for name in dir(bpy.app.handlers)
            if not name.startswith("_") and isinstance(getattr(bpy.app.handlers, name), list)}


def test_register_unregister_cycles():
    installed_addon()
    assert ADDON_MODULE in bpy.context.preferences.addons
    assert hasattr(bpy.types, "ARCHHEAD_PT_main")
    assert hasattr(bpy.ops.archhead, "import_sequence")
    handlers = _handler_counts()
    for _ in range(2):
        bpy.ops.preferences.addon_disable(module=ADDON_MODULE)
        assert ADDON_MODULE not in bpy.context.preferences.addons
        assert not hasattr(bpy.types, "ARCHHEAD_PT_main")
        assert not hasattr(bpy.types, "ARCHHEAD_OT_import_sequence")
        bpy.ops.preferences.addon_enable(module=ADDON_MODULE)
        assert hasattr(bpy.types, "ARCHHEAD_PT_main")
    assert _handler_counts() == handlers
    prefs = bpy.context.preferences.addons[ADDON_MODULE].preferences
    assert prefs.flame_model_path == "" and hasattr(prefs, "backend_python")


def test_manifest_names_file_permission():
    import tomllib

    from addon_env import REPO_ROOT

    manifest = tomllib.loads((REPO_ROOT / "blender_manifest.toml").read_text())
    assert manifest["id"] == "archhead" and manifest["blender_version_min"] == "4.2.0"
    assert manifest["permissions"]["files"]
