"""Installs the add-on into the bpy module the way Blender does: the extension zip that
`make extension` builds (scripts/build_extension.py), then `extensions.package_install_files`
(which also installs the zip's wheel of archhead_addon and archhead_blender)."""

from __future__ import annotations

import importlib
import tempfile
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
REPO_MODULE = "archhead_tests"
ADDON_MODULE = f"bl_ext.{REPO_MODULE}.archhead"
_state: dict = {}


def build_extension(out_dir: Path) -> Path:
    from scripts.build_extension import build

    return build(out_dir)


def installed_addon():
    """Build, install and enable once per test session; returns the add-on's module."""
    if "module" not in _state:
        import bpy

        work = Path(tempfile.mkdtemp(prefix="archhead_ext_"))
        zip_path = build_extension(work)
        repo_dir = work / "repo"
        repo_dir.mkdir()
        bpy.context.preferences.extensions.repos.new(
            name=REPO_MODULE, module=REPO_MODULE, custom_directory=str(repo_dir), source="USER"
        )
        bpy.ops.extensions.package_install_files(
            filepath=str(zip_path), repo=REPO_MODULE, enable_on_install=True
        )
        _state["module"] = importlib.import_module(ADDON_MODULE)
        _state["zip"] = zip_path
    return _state["module"]


def uninstall_addon() -> None:
    """Remove the wheel contents installed_addon() left. Blender puts an extension's wheels
    into the user profile's shared `extensions/.local` site-packages, which every later bpy
    process puts on sys.path: left there, a stale copy of the packages would shadow the
    checkout. Removed by name, since tests that load files may have dropped the session's
    repository from the preferences already."""
    if "module" not in _state:
        return
    import shutil

    import bpy

    local = Path(bpy.utils.user_resource("EXTENSIONS", path=".local"))
    for site in local.glob("lib/python*/site-packages"):
        for name in ("archhead_addon", "archhead_blender", "archhead-*.dist-info"):
            for path in site.glob(name):
                shutil.rmtree(path)
    _state.clear()


def state() -> dict:
    """What installed_addon() built: {"module", "zip"}."""
    return _state
