"""Train Avatar and Cancel Training: a modal operator around archhead_blender.training.

Its properties' defaults are the command line's preset (train/config.py DEFAULT_PRESET); only
the ones the user set override it, so both start the same avatar."""

from __future__ import annotations

import bpy

from archhead_addon.io.errors import InputError
from archhead_addon.train.config import config_data
from archhead_blender.avatar_objects import head_of
from archhead_blender.training import (
    current_run,
    finish_training,
    start_training,
    training_settings,
)

from .backend_watch import BackendWatch

PRESET = config_data()  # read once: the properties' defaults
OVERRIDABLE = ("resolution", "stage1_steps", "stage2_steps")


class ARCHHEAD_OT_train_avatar(BackendWatch, bpy.types.Operator):
    """Train an avatar from video frames and their tracking in a background process"""

    bl_idname = "archhead.train_avatar"
    bl_label = "Train Avatar"
    status_prefix = "ArchHead training"

    frames_dir: bpy.props.StringProperty(
        name="Frames", subtype="DIR_PATH", description="Folder of numbered video frames"
    )
    tracking: bpy.props.StringProperty(
        name="Tracking",
        subtype="FILE_PATH",
        description="The frames' FLAME tracking (any format the importer reads)",
    )
    out_dir: bpy.props.StringProperty(
        name="Output", subtype="DIR_PATH", description="Checkpoints, config and log go here"
    )
    resolution: bpy.props.IntProperty(name="Resolution", min=32, default=PRESET["resolution"])
    stage1_steps: bpy.props.IntProperty(name="Stage 1 steps", min=0, default=PRESET["stage1_steps"])
    stage2_steps: bpy.props.IntProperty(name="Stage 2 steps", min=0, default=PRESET["stage2_steps"])
    resume: bpy.props.BoolProperty(name="Resume", description="Continue the run in Output")
    base_config: bpy.props.StringProperty(
        name="Base config",
        subtype="FILE_PATH",
        description="Optional training config (JSON) in place of the command line's preset; "
        "the fields above override its values where you changed them",
    )

    def invoke(self, context, event):
        return context.window_manager.invoke_props_dialog(self, width=420)

    def execute(self, context):
        head = head_of(context.active_object)
        try:
            settings = training_settings(
                self.overrides(), bpy.path.abspath(self.base_config) if self.base_config else ""
            )
            self.run = start_training(
                context,
                bpy.path.abspath(self.frames_dir),
                bpy.path.abspath(self.tracking),
                bpy.path.abspath(self.out_dir),
                settings,
                self.resume,
                head.name if head else None,
            )
        except (InputError, OSError, ValueError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        return self.watch(context)

    def overrides(self) -> dict:
        """The fields the user (or a script) set; the rest come from the base config."""
        return {
            name: getattr(self, name)
            for name in OVERRIDABLE
            if self.properties.is_property_set(name)
        }

    def finish_run(self, context):
        return finish_training(context, self.run)


class ARCHHEAD_OT_cancel_training(bpy.types.Operator):
    """Stop training: the backend saves a checkpoint and exits"""

    bl_idname = "archhead.cancel_training"
    bl_label = "Cancel Training"
    bl_options = {"INTERNAL"}

    @classmethod
    def poll(cls, context):
        return current_run() is not None

    def execute(self, context):
        current_run().backend.cancel()
        return {"FINISHED"}
