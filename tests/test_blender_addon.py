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


def test_extension_zip_holds_the_addon_alone():
    """The zip `make extension` builds: `platforms` set, a wheel with the core and the
    Blender side, and nothing of the checkout besides the add-on."""
    import tomllib
    import zipfile

    from addon_env import REPO_ROOT, installed_addon, state

    installed_addon()
    with zipfile.ZipFile(state()["zip"]) as zf:
        names = zf.namelist()
        manifest = tomllib.loads(zf.read("blender_manifest.toml").decode())
        (wheel,) = [n for n in names if n.startswith("wheels/")]
        assert manifest["wheels"] == [f"./{wheel}"]
    assert manifest["platforms"] == ["linux-x64"]
    assert {n.split("/")[0] for n in names} == {"__init__.py", "blender_manifest.toml",
                                                 "operators", "panels", "wheels"}
    assert not [n for n in names if "__pycache__" in n or n.endswith((".so", ".pyc"))]
    project = tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())
    assert project["project"]["version"] == manifest["version"]  # the version in one place


def test_one_input_error_whichever_way_the_core_is_reached(tmp_path):
    """The extension imports the core as `archhead_addon`, like everyone else: an error
    raised through the installed add-on is caught as archhead_addon's InputError."""
    import importlib

    import pytest

    from archhead_addon.io.errors import InputError

    addon = installed_addon()
    operators = importlib.import_module(f"{addon.__name__}.operators.import_sequence")
    assert operators.InputError is InputError
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a sequence")
    with pytest.raises(InputError):
        importlib.import_module("archhead_blender.importing").import_sequence(bpy.context, bad)
    with pytest.raises(RuntimeError, match="not a readable"):  # reported, not crashed
        bpy.ops.archhead.import_sequence(filepath=str(bad))


def test_train_operator_starts_from_the_command_lines_preset():
    """Unchanged fields come from the `cpu` preset (train/config.py DEFAULT_PRESET), as on
    the command line; only what the user set overrides it."""
    import importlib

    from archhead_addon.train.config import DEFAULT_PRESET, config_data

    addon = installed_addon()
    module = importlib.import_module(f"{addon.__name__}.operators.train_operator")
    training = importlib.import_module("archhead_blender.training")
    preset = config_data(DEFAULT_PRESET)
    assert DEFAULT_PRESET == "cpu"
    props = bpy.ops.archhead.train_avatar.get_rna_type().properties
    for name in module.OVERRIDABLE:
        assert props[name].default == preset[name]
    assert training.training_settings({}) == preset
    assert training.training_settings({"stage1_steps": 7}) == {**preset, "stage1_steps": 7}
