"""A scene with an imported demo head and a tiny untrained avatar on the built-in model, for
the Blender avatar tests (the avatar model's own initialisation and checkpoint writer)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import bpy
import numpy as np
from addon_env import installed_addon

from archhead_addon.flame import load_model
from archhead_addon.sequences.canonical import write_canonical
from archhead_addon.sequences.demo import demo_sequence

DEMO_FRAMES = 6
_checkpoints: dict[str, Path] = {}


def tiny_checkpoint(folder: Path) -> Path:
    """An untrained avatar of the built-in model (built once per test session)."""
    if "path" not in _checkpoints:
        import torch

        from archhead_addon.avatar.checkpoint import save_avatar
        from archhead_addon.avatar.model import ArchHeadAvatar

        torch.manual_seed(0)
        path = Path(folder) / "tiny_avatar.npz"
        save_avatar(path, ArchHeadAvatar.create(load_model()))
        _checkpoints["path"] = path
    return _checkpoints["path"]


def demo_sequence_moving(frames: int = DEMO_FRAMES):
    """The demo talking head, also translating sideways (so the root bone carries a
    translation besides the expressions' joint shift)."""
    seq = demo_sequence(frames=frames, image_size=(64, 64))
    x = np.linspace(-0.03, 0.03, frames)
    return replace(seq, translation=np.stack([x, 0.01 * x, np.zeros(frames)], 1))


def demo_scene(folder: Path, frames: int = DEMO_FRAMES):
    """A fresh scene with the moving demo head imported: (addon module, head, sequence)."""
    addon = installed_addon()
    bpy.ops.wm.read_homefile(use_empty=True)
    path = Path(folder) / "demo.npz"
    seq = demo_sequence_moving(frames)
    write_canonical(seq, path)
    assert bpy.ops.archhead.import_sequence(filepath=str(path)) == {"FINISHED"}
    return addon, bpy.data.objects["demo"], seq


def load_avatar(head, checkpoint: Path):
    view_layer = bpy.context.view_layer
    view_layer.objects.active = head
    assert bpy.ops.archhead.load_avatar(filepath=str(checkpoint)) == {"FINISHED"}
    return bpy.data.objects[f"{head.name}_avatar"]


def point_count(obj) -> int:
    return len(obj.data.vertices)


def positions(obj) -> np.ndarray:
    co = np.empty(3 * len(obj.data.vertices), np.float32)
    obj.data.vertices.foreach_get("co", co)
    return co.reshape(-1, 3)


def load_rgba(path) -> np.ndarray:
    """An image file as (H,W,4) float32 RGBA, top row first, read through Blender."""
    image = bpy.data.images.load(str(path))
    try:
        w, h = image.size
        return np.array(image.pixels[:], np.float32).reshape(h, w, 4)[::-1]
    finally:
        bpy.data.images.remove(image)
