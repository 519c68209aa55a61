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
    return build_head(context, model, seq, ImportOptions(**options), info)
