"""File > Import > Tracked FLAME sequence: reads any supported format into a rigged head
(archhead_blender.importing does the work)."""

from __future__ import annotations

import warnings
from pathlib import Path

import bpy
from bpy_extras.io_utils import ImportHelper

from archhead_addon.io.errors import InputError, InputWarning
from archhead_blender.importing import import_sequence
from archhead_blender.preferences import get_preferences


def frame_selected(context) -> None:
    """Every 3D view looks at the selection (the head is about 20 cm wide and could
    otherwise sit unseen inside the default cube)."""
    for window in context.window_manager.windows:
        for area in window.screen.areas:
            region = next((r for r in area.regions if r.type == "WINDOW"), None)
            if area.type == "VIEW_3D" and region is not None:
                with context.temp_override(window=window, area=area, region=region):
                    bpy.ops.view3d.view_selected()


class ARCHHEAD_OT_import_sequence(bpy.types.Operator, ImportHelper):
    """Import a tracked FLAME sequence as a rigged, shape-keyed, animated head"""

    bl_idname = "archhead.import_sequence"
    bl_label = "Import Tracked FLAME Sequence"
    bl_options = {"REGISTER", "UNDO", "PRESET"}

    filename_ext = ""
    filter_glob: bpy.props.StringProperty(
        default="*.npz;*.frame;*.json;*.pt;*.pkl", options={"HIDDEN"}
    )
    directory: bpy.props.StringProperty(subtype="DIR_PATH", options={"HIDDEN", "SKIP_SAVE"})

    frame_start: bpy.props.IntProperty(
        name="First frame", min=0, default=0, description="First sequence frame to import (0-based)"
    )
    frame_end: bpy.props.IntProperty(
        name="Last frame",
        min=-1,
        default=-1,
        description="Last sequence frame to import; -1 = the end",
    )
    stride: bpy.props.IntProperty(
        name="Stride", min=1, default=1, description="Import every n-th frame"
    )
    target_fps: bpy.props.FloatProperty(
        name="Scene fps",
        min=0.0,
        default=0.0,
        description="Scene frame rate; 0 = the sequence's. Keys stay at their time",
    )
    n_expr: bpy.props.IntProperty(
        name="Expressions",
        min=0,
        max=400,
        default=100,
        description="Expression components kept as shape keys (fewer = lighter scene)",
    )
    use_camera: bpy.props.BoolProperty(
        name="Camera", default=True, description="Create the tracked camera when there is one"
    )
    pose_correctives: bpy.props.EnumProperty(
        name="Pose correctives",
        items=(
            (
                "DRIVERS",
                "Driven by bones",
                "36 corrective shape keys driven by simple "
                "expressions of the bones' rotations: they follow any later bone edit",
            ),
            (
                "KEYFRAMES",
                "Keyframed",
                "36 corrective shape keys keyframed from the tracked rotations",
            ),
            ("NONE", "None", "No pose correctives (lighter, not exact)"),
        ),
        default="DRIVERS",
    )

    def execute(self, context):
        path = Path(self.filepath)
        if not self.filepath or (self.directory and path == Path(self.directory)):
            path = Path(self.directory or self.filepath)
        prefs = get_preferences(context)
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", InputWarning)
                obj = import_sequence(
                    context,
                    path,
                    self.import_options(),
                    model_path=prefs.flame_model_path if prefs else "",
                )
        except (InputError, OSError, ValueError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        for w in caught:
            if issubclass(w.category, InputWarning):
                self.report({"WARNING"}, str(w.message))
        if not bpy.app.background:
            frame_selected(context)
        self.report({"INFO"}, f"Imported {obj.name}")
        return {"FINISHED"}

    def import_options(self) -> dict:
        return {
            "frame_start": self.frame_start,
            "frame_end": self.frame_end,
            "stride": self.stride,
            "fps": self.target_fps or None,
            "n_expr": self.n_expr,
            "camera": self.use_camera,
            "pose_correctives": self.pose_correctives,
        }
