"""Avatar from Video and its Cancel: a modal operator around archhead_blender.video_avatar
(track, import, train, load in one output folder; run again on the folder to go on)."""

from __future__ import annotations

import bpy

from archhead_addon.io.errors import InputError
from archhead_addon.train.config import DEFAULT_PRESET
from archhead_blender.state import STATE
from archhead_blender.video_avatar import (
    current_video_run,
    finish_video_avatar,
    folder_state,
    start_video_avatar,
)

from .backend_watch import BackendWatch
from .track_operator import frame_budget_property
from .train_operator import PRESET_ITEMS, time_limit_property

DIALOG_KEY = "avatar_from_video"  # its remembered fields in STATE.dialog_fields
REMEMBERED = (
    "video",
    "out_dir",
    "preset",
    "minutes",
    "frames",
    "frame_budget",
    "size",
    "photometric",
)


class ARCHHEAD_OT_avatar_from_video(BackendWatch, bpy.types.Operator):
    """Track a face video, import the tracked head, train an avatar on it and load it, in
    background processes; run it again on the same Output to go on after a stop"""

    bl_idname = "archhead.avatar_from_video"
    bl_label = "Avatar from Video"
    status_prefix = "ArchHead avatar from video"

    video: bpy.props.StringProperty(
        name="Video", subtype="FILE_PATH", description="Video file, or a folder of frames"
    )
    out_dir: bpy.props.StringProperty(
        name="Output",
        subtype="DIR_PATH",
        description="Holds everything (data/: the tracking, run/: the training); created. "
        "Run again on the same folder to go on from where a stop left it",
    )
    preset: bpy.props.EnumProperty(name="Preset", items=PRESET_ITEMS, default=DEFAULT_PRESET)
    minutes: time_limit_property(
        "Finish within this many minutes from the start: training gets what tracking leaves, "
        "the preset's steps shortened to fit (0: the preset's steps, however long they take)"
    )
    frames: bpy.props.IntProperty(
        name="Frames", min=0, default=0, description="Track only the first N frames (0: all)"
    )
    frame_budget: frame_budget_property()
    size: bpy.props.IntProperty(
        name="Size", min=64, max=2048, default=512, description="The tracked frames' size"
    )
    photometric: bpy.props.BoolProperty(
        name="Refine on the frames",
        default=True,
        description="After the landmark fit, refine the tracking against the frames' colours",
    )

    def invoke(self, context, event):
        for name, value in STATE.dialog_fields.get(DIALOG_KEY, {}).items():
            setattr(self, name, value)
        return context.window_manager.invoke_props_dialog(self, width=480)

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        for name in REMEMBERED:
            layout.prop(self, name)
        state = folder_state(self.out_dir)
        if state:
            layout.label(text=state, icon="INFO")

    def execute(self, context):
        STATE.dialog_fields[DIALOG_KEY] = {
            n: getattr(self, n) for n in REMEMBERED if self.properties.is_property_set(n)
        }
        if not self.out_dir.strip():
            self.report({"ERROR"}, "Output: choose a folder for the avatar (it is created)")
            return {"CANCELLED"}
        try:
            self.run = start_video_avatar(
                context,
                bpy.path.abspath(self.video) if self.video.strip() else "",
                bpy.path.abspath(self.out_dir).rstrip("/\\"),
                self.preset,
                self.frames,
                self.size,
                self.photometric,
                self.frame_budget,
                self.minutes,
            )
        except (InputError, OSError, ValueError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        return self.watch(context)

    def advance(self, context) -> bool:
        return self.run.update(context)

    def finish_run(self, context):
        return finish_video_avatar(context, self.run)


class ARCHHEAD_OT_cancel_video_avatar(bpy.types.Operator):
    """Stop Avatar from Video (training saves a checkpoint first); run Avatar from Video on
    the same Output again to go on"""

    bl_idname = "archhead.cancel_video_avatar"
    bl_label = "Cancel Avatar from Video"
    bl_options = {"INTERNAL"}

    @classmethod
    def poll(cls, context):
        return current_video_run() is not None

    def execute(self, context):
        current_video_run().cancel()
        return {"FINISHED"}
