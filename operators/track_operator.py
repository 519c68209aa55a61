"""Track Video and Cancel Tracking: a modal operator around archhead_blender.tracking."""

from __future__ import annotations

import bpy

from archhead_addon.track import FRAME_BUDGET
from archhead_blender.tracking import (
    current_tracking,
    finish_tracking,
    start_tracking,
)

from .backend_watch import BackendWatch


def frame_budget_property():
    """Track Video's and Avatar from Video's "Most frames" (`track --frame-budget`)."""
    return bpy.props.IntProperty(
        name="Most frames",
        min=0,
        default=FRAME_BUDGET,
        description="Track at most this many frames, one in 2, 3 ... of a longer "
        "clip: tracking's time grows with the frames, training's does not (0: every frame)",
    )


class ARCHHEAD_OT_track_video(BackendWatch, bpy.types.Operator):
    """Track a face video into a training folder in a background process, then import the
    tracked head"""

    bl_idname = "archhead.track_video"
    bl_label = "Track Video"
    status_prefix = "ArchHead tracking"

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
    frame_budget: frame_budget_property()
    size: bpy.props.IntProperty(name="Size", min=64, max=2048, default=512)
    photometric: bpy.props.BoolProperty(
        name="Refine on the frames",
        default=True,
        description="After the landmark fit, refine the tracking against the frames' colours "
        "(one texture for the whole clip)",
    )
    static_offset: bpy.props.BoolProperty(
        name="Static offset",
        default=False,
        description="Let the refinement move the head's vertices where the shape space cannot "
        "reach the person",
    )

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
                self.photometric,
                self.static_offset,
                frame_budget=self.frame_budget,
            )
        except (OSError, ValueError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        return self.watch(context)

    def finish_run(self, context):
        return finish_tracking(context, self.run)


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
