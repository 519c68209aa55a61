"""Installs the add-on into the bpy module the way Blender does: the extension build of this
repository (Blender's own `blender_ext.py build`), then `extensions.package_install_files`."""

from __future__ import annotations

import importlib
import subprocess
import sys
import tempfile
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
REPO_MODULE = "archhead_tests"
ADDON_MODULE = f"bl_ext.{REPO_MODULE}.archhead"
_state: dict = {}


def build_extension(out_dir: Path) -> Path:
    import bpy

    tool = Path(bpy.utils.system_resource("SCRIPTS")) / "addons_core/bl_pkg/cli/blender_ext.py"
    subprocess.run([sys.executable, str(tool), "build", "--source-dir", str(REPO_ROOT),
                    "--output-dir", str(out_dir)], check=True, capture_output=True, text=True)
    (zip_path,) = out_dir.glob("archhead-*.zip")
    return zip_path


def installed_addon():
    """Build, install and enable once per test session; returns the add-on's module."""
    if "module" not in _state:
        import bpy

        work = Path(tempfile.mkdtemp(prefix="archhead_ext_"))
        zip_path = build_extension(work)
        repo_dir = work / "repo"
        repo_dir.mkdir()
        bpy.context.preferences.extensions.repos.new(
            name=REPO_MODULE, module=REPO_MODULE, custom_directory=str(repo_dir), source="USER")
        bpy.ops.extensions.package_install_files(filepath=str(zip_path), repo=REPO_MODULE,
                                                 enable_on_install=True)
        _state["module"] = importlib.import_module(ADDON_MODULE)
        _state["zip"] = zip_path
    return _state["module"]
