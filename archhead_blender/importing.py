"""Import a tracked FLAME sequence: read any supported format, build the rigged head."""

from __future__ import annotations

from pathlib import Path

from archhead_addon.sequences import read_sequence

from .head_builder import ImportOptions, build_head
from .model_cache import head_model


def import_sequence(context, path, options: dict | None = None, model_path: str = ""):
    """Read `path`, fit it to the model and build the head; returns the armature object.

    Shared by the operator, scripts and tests (`blender -b --python` or the bpy module).
    """
    options = dict(options or {})
    model = head_model(model_path)
    seq = read_sequence(path).fit_to_model(model)
    end = options.pop("frame_end", -1)
    seq = seq.subset(
        options.pop("frame_start", 0), None if end < 0 else end + 1, options.pop("stride", 1)
    )
    info = {"sequence": str(path), "format": seq.format, "frames": len(seq), "source_fps": seq.fps}
    options.setdefault("name", Path(path).stem or "ArchHead")
    rig = build_head(context, model, seq, ImportOptions(**options), info)
    select_imported(context, rig)
    return rig


def select_imported(context, rig) -> None:
    """Only the new rig and head selected, the rig active (as Blender's importers leave it)."""
    view_layer = context.view_layer
    for obj in view_layer.objects:
        if obj.select_get(view_layer=view_layer):
            obj.select_set(False, view_layer=view_layer)
    for obj in (rig, *rig.children):
        if obj.name in view_layer.objects and obj.type in {"ARMATURE", "MESH"}:
            obj.select_set(True, view_layer=view_layer)
    view_layer.objects.active = rig
