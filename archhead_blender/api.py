"""The public API of ArchHead for scripts and benchmarks (scripts/, benchmarks/, render-farm
jobs): the one module they import. It re-exports what they call, from the core and from the
Blender side, and `enable_addon`, which makes the add-on's operators available in this
Blender (or bpy-module) process. Everything it names is importable without sys.path changes:
`archhead_addon` and `archhead_blender` are installed packages (the project's environment, or
the extension's wheel in Blender).
"""

from __future__ import annotations

import atexit
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import bpy

from archhead_addon.avatar.frame_selection import parse_frames
from archhead_addon.avatar.lod import resolution_for_lod
from archhead_addon.avatar.point_attributes import point_attributes
from archhead_addon.backend_process import python_with_torch, train_command
from archhead_addon.flame import load_model
from archhead_addon.sequences import write_canonical
from archhead_addon.sequences.demo import demo_sequence
from archhead_addon.timing import Steps, Stopwatch, restart_with_threads, time_calls
from archhead_addon.train.run_folder import RunFolder

from .avatar_session import session
from .batch_render import read_image, render_frames, scene_avatars, write_png
from .compat import eevee_engine
from .decoding import decode_frames
from .lod_driver import drive_lod_by_distance
from .point_instances import write_points
from .scene_state import avatar_lod, frame_codes
from .synthetic_subject import DEFAULT_SAMPLES as SUBJECT_SAMPLES
from .synthetic_subject import render_subject

__all__ = [
    "RunFolder",
    "SUBJECT_SAMPLES",
    "Steps",
    "Stopwatch",
    "avatar_lod",
    "decode_frames",
    "demo_sequence",
    "drive_lod_by_distance",
    "eevee_engine",
    "enable_addon",
    "frame_codes",
    "load_model",
    "parse_frames",
    "point_attributes",
    "python_with_torch",
    "read_image",
    "render_frames",
    "render_subject",
    "resolution_for_lod",
    "restart_with_threads",
    "scene_avatars",
    "scratch_folder",
    "script_args",
    "session",
    "time_calls",
    "train_command",
    "untrained_checkpoint",
    "write_canonical",
    "write_png",
    "write_points",
]

ADDON_ID = "archhead"  # blender_manifest.toml's id: Blender names the module bl_ext.<repo>.<id>
CHECKOUT_REPO = "archhead_checkout"


def script_args(argv: list[str]) -> list[str]:
    """A script's own arguments: after `--` under `blender -b --python`, else argv[1:]."""
    return argv[argv.index("--") + 1 :] if "--" in argv else argv[1:]


def scratch_folder(prefix: str = "archhead_") -> Path:
    """A new temporary folder, removed with everything in it when this process exits (links
    in it are removed, not followed)."""
    folder = Path(tempfile.mkdtemp(prefix=prefix))
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    return folder


def enable_addon() -> str:
    """Enable ArchHead and return its module name: the add-on already enabled, else an
    installed extension, else (a checkout) this checkout as a local extension repository."""
    import addon_utils

    suffix = f".{ADDON_ID}"
    for addon in bpy.context.preferences.addons:
        if addon.module.endswith(suffix):
            return addon.module
    installed = [m.__name__ for m in addon_utils.modules() if m.__name__.endswith(suffix)]
    module = installed[0] if installed else _checkout_extension()
    bpy.ops.preferences.addon_enable(module=module)
    return module


def _checkout_extension() -> str:
    root = Path(__file__).resolve().parents[1]
    if not (root / "blender_manifest.toml").is_file():
        raise RuntimeError(
            "ArchHead is not installed in this Blender: install the extension "
            "(make extension) and enable it"
        )
    folder = scratch_folder("archhead_repo_")
    (folder / ADDON_ID).symlink_to(root, target_is_directory=True)
    bpy.context.preferences.extensions.repos.new(
        name=CHECKOUT_REPO, module=CHECKOUT_REPO, custom_directory=str(folder), source="USER"
    )
    return f"bl_ext.{CHECKOUT_REPO}.{ADDON_ID}"


def untrained_checkpoint(path) -> Path:
    """An untrained avatar of the built-in model at `path`, made by the backend (it needs
    torch, which Blender's side never imports); its decode cost equals a trained one's."""
    python = python_with_torch() or sys.executable
    subprocess.run([python, "-m", "archhead_addon.avatar.untrained", str(path)], check=True)
    return Path(path)
