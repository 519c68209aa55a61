"""Track Video and Cancel Tracking: a modal operator around archhead_blender.tracking."""

from __future__ import annotations

import time

import bpy

from archhead_blender.tracking import (
    current_tracking,
    finish_tracking,
    start_tracking,
)
from archhead_blender.training import POLL_S


class ARCHHEAD_OT_track_video(bpy.types.Operator):
    """Track a face video into a training folder in a background process, then import the
    tracked head"""

    bl_idname = "archhead.track_video"
    bl_label = "Track Video"

    video: bpy.props.StringProperty(
        name="Video", subtype="FILE_PATH", description="Video file, or a folder of frames"
    )
    out_dir: bpy.props.StringProperty(
        name="Output",
        subtype="DIR_PATH",
        description="Training folder to write (frames, masks, tracking.npz); created",
    )
    frames: bpy.props.IntProperty(
        name="Frames", min=0, default=0, description="Track only the first N frames (0: all)"
    )
    size: bpy.props.IntProperty(name="Size", min=64, max=2048, default=512)

    def invoke(self, context, event):
        return context.window_manager.invoke_props_dialog(self, width=420)

    def execute(self, context):
        if not self.video or not self.out_dir:
            self.report({"ERROR"}, "choose a video and an output folder")
            return {"CANCELLED"}
        try:
            self.run = start_tracking(
                context,
                bpy.path.abspath(self.video),
                bpy.path.abspath(self.out_dir).rstrip("/\\"),
                self.frames,
                self.size,
            )
        except (OSError, ValueError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        if bpy.app.background:  # no event loop: wait here
            while not self.run.update():
                time.sleep(POLL_S)
            return self._finish(context)
        wm = context.window_manager
        self.timer = wm.event_timer_add(POLL_S, window=context.window)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        done = self.run.update()
        if context.workspace is not None:
            context.workspace.status_text_set(
                None if done else f"ArchHead tracking: {self.run.summary()}"
            )
        for area in context.screen.areas if context.screen else ():
            if area.type == "VIEW_3D":
                area.tag_redraw()
        if not done:
            return {"PASS_THROUGH"}
        context.window_manager.event_timer_remove(self.timer)
        return self._finish(context)

    def _finish(self, context):
        try:
            kind, message = finish_tracking(context, self.run)
        except (OSError, ValueError) as exc:
            kind, message = "ERROR", str(exc)
        self.report({kind}, message)
        return {"FINISHED"} if kind == "INFO" else {"CANCELLED"}


class ARCHHEAD_OT_cancel_tracking(bpy.types.Operator):
    """Stop tracking: the backend exits and leaves no output folder"""

    bl_idname = "archhead.cancel_tracking"
    bl_label = "Cancel Tracking"
    bl_options = {"INTERNAL"}

    @classmethod
    def poll(cls, context):
        return current_tracking() is not None

    def execute(self, context):
        current_tracking().backend.cancel()
        return {"FINISHED"}
