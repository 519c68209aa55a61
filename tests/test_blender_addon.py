"""The extension installs, registers, unregisters and registers again cleanly."""

import bpy
import pytest

pytestmark = pytest.mark.blender


def _handler_counts():
    return {
        name: len(getattr(bpy.app.handlers, name))
        for name in dir(bpy.app.handlers)
        if not name.startswith("_") and isinstance(getattr(bpy.app.handlers, name), list)
    }


def test_register_unregister_cycles(addon):
    module = addon.__name__
    assert module in bpy.context.preferences.addons
    assert hasattr(bpy.types, "ARCHHEAD_PT_main")
    assert hasattr(bpy.ops.archhead, "import_sequence")
    handlers = _handler_counts()
    for _ in range(2):
        bpy.ops.preferences.addon_disable(module=module)
        assert module not in bpy.context.preferences.addons
        assert not hasattr(bpy.types, "ARCHHEAD_PT_main")
        assert not hasattr(bpy.types, "ARCHHEAD_OT_import_sequence")
        bpy.ops.preferences.addon_enable(module=module)
        assert hasattr(bpy.types, "ARCHHEAD_PT_main")
    assert _handler_counts() == handlers
    prefs = bpy.context.preferences.addons[module].preferences
    assert prefs.flame_model_path == "" and hasattr(prefs, "backend_python")


def test_manifest_names_file_permission(repo_root):
    import tomllib

    manifest = tomllib.loads((repo_root / "blender_manifest.toml").read_text())
    assert manifest["id"] == "archhead" and manifest["blender_version_min"] == "4.2.0"
    assert manifest["permissions"]["files"]


def test_extension_zip_holds_the_addon_alone(extension_zip, repo_root):
    """The zip `make extension` builds: `platforms` set, a wheel with the core and the
    Blender side, and nothing of the checkout besides the add-on."""
    import tomllib
    import zipfile

    with zipfile.ZipFile(extension_zip) as zf:
        names = zf.namelist()
        manifest = tomllib.loads(zf.read("blender_manifest.toml").decode())
        (wheel,) = [n for n in names if n.startswith("wheels/")]
        assert manifest["wheels"] == [f"./{wheel}"]
    assert manifest["platforms"] == ["linux-x64"]
    assert {n.split("/")[0] for n in names} == {
        "__init__.py",
        "blender_manifest.toml",
        "operators",
        "panels",
        "wheels",
    }
    assert not [n for n in names if "__pycache__" in n or n.endswith((".so", ".pyc"))]
    project = tomllib.loads((repo_root / "pyproject.toml").read_text())
    assert project["project"]["version"] == manifest["version"]  # the version in one place


def test_one_input_error_whichever_way_the_core_is_reached(addon, tmp_path):
    """The extension imports the core as `archhead_addon`, like everyone else: an error
    raised through the installed add-on is caught as archhead_addon's InputError."""
    import importlib

    from archhead_addon.io.errors import InputError

    operators = importlib.import_module(f"{addon.__name__}.operators.import_sequence")
    assert operators.InputError is InputError
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a sequence")
    with pytest.raises(InputError):
        importlib.import_module("archhead_blender.importing").import_sequence(bpy.context, bad)
    with pytest.raises(RuntimeError, match="not a readable"):  # reported, not crashed
        bpy.ops.archhead.import_sequence(filepath=str(bad))


def test_train_operator_starts_from_the_command_lines_preset(addon):
    """Unchanged fields come from the `cpu` preset (train/config.py DEFAULT_PRESET), as on
    the command line; only what the user set overrides it."""
    import importlib

    from archhead_addon.train.config import DEFAULT_PRESET, config_data

    module = importlib.import_module(f"{addon.__name__}.operators.train_operator")
    training = importlib.import_module("archhead_blender.training")
    preset = config_data(DEFAULT_PRESET)
    assert DEFAULT_PRESET == "cpu"
    props = bpy.ops.archhead.train_avatar.get_rna_type().properties
    for name in module.OVERRIDABLE:
        assert props[name].default == preset[name]
    assert training.training_settings({}) == preset
    assert training.training_settings({"stage1_steps": 7}) == {**preset, "stage1_steps": 7}


def test_preset_tooltips_give_the_presets_steps(addon):
    """The dialog's tooltip of each preset names its steps (a preset's steps changed and its
    tooltip did not, once)."""
    import importlib
    import re

    from archhead_addon.train.config import PRESETS, STAGE_STEPS, config_data

    module = importlib.import_module(f"{addon.__name__}.operators.train_operator")
    for name in PRESETS:
        stated = re.search(r"([\d,]+) steps", module.PRESET_HELP[name])
        assert stated, f"the {name} tooltip names no steps"
        total = sum(config_data(name).get(key, 0) for key in STAGE_STEPS)
        assert int(stated.group(1).replace(",", "")) == total, name


INSTALL_AND_REPORT = """
import sys, bpy
from pathlib import Path
zip_path, repo = Path(sys.argv[1]), Path(sys.argv[2])
bpy.context.preferences.extensions.repos.new(name="bare", module="bare",
                                            custom_directory=str(repo), source="USER")
bpy.ops.extensions.package_install_files(filepath=str(zip_path), repo="bare",
                                         enable_on_install=True)
import archhead_addon
print("core:", archhead_addon.__file__)
print("registered:", hasattr(bpy.types, "ARCHHEAD_PT_main"), hasattr(bpy.ops.archhead,
                                                                      "import_sequence"))
"""


def test_addon_loads_without_the_compiled_kernel(extension_zip, tmp_path):
    """What a platform without the kernel and without a compiler gets (the kernel is
    otherwise compiled on first use): the core and Blender side without
    libarchhead_splat.so. The add-on registers and names the feature that needs it."""
    import subprocess
    import sys
    import zipfile

    site = tmp_path / "site"
    with zipfile.ZipFile(extension_zip) as zf:
        (wheel,) = [n for n in zf.namelist() if n.startswith("wheels/")]
        zf.extract(wheel, tmp_path)
    with zipfile.ZipFile(tmp_path / wheel) as whl:
        whl.extractall(site, [n for n in whl.namelist() if "/_build/" not in n])
    (tmp_path / "repo").mkdir()
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path), "PYTHONPATH": str(site)}
    env["CXX"] = "no-such-compiler"
    done = subprocess.run(
        [sys.executable, "-c", INSTALL_AND_REPORT, str(extension_zip), str(tmp_path / "repo")],
        env=env,
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert f"core: {site}" in done.stdout
    assert "registered: True True" in done.stdout
    assert "Exact splat renders" in done.stdout and "compiled splat kernel" in done.stdout
