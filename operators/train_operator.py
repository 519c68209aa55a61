"""Train Avatar and Cancel Training: a modal operator around archhead_blender.training.

Its properties' defaults are the command line's preset (train/config.py DEFAULT_PRESET);
choosing another preset shows that preset's values; only the fields the user (or a script)
set override the preset or base config, so the dialog and the command line start the same
avatar. The dialog opens with the fields it last ran with (kept even when the run failed to
start), else filled in from the active head when it came from Track Video."""

from __future__ import annotations

from pathlib import Path

import bpy

from archhead_addon.io.errors import InputError
from archhead_addon.train.config import DEFAULT_PRESET, PRESETS, config_data
from archhead_addon.train.dataset import FRAMES_DIR, TRACKING_FILE
from archhead_blender.avatar_objects import head_of
from archhead_blender.state import STATE
from archhead_blender.training import (
    current_run,
    finish_training,
    start_training,
    training_settings,
)

from .backend_watch import BackendWatch

PRESET = config_data()  # read once: the properties' defaults
OVERRIDABLE = ("resolution", "stage1_steps", "stage2_steps")
DIALOG_KEY = "train_avatar"  # its remembered fields in STATE.dialog_fields
REMEMBERED = ("frames_dir", "tracking", "out_dir", "preset", "minutes", "resume", "base_config")
# Times measured on the project's 2-core machine (a loaded machine takes longer): the real
# subjects' runs of docs/quality.md.
PRESET_HELP = {
    "cpu": "The CPU avatar: 37,530 steps at 256 px (30-45 min on 2 cores)",
    "cpu_short": "The CPU avatar in 4,600 steps at 256 px (about 10 min on 2 cores)",
    "gpu_paper": "The paper's settings, for a CUDA GPU (45,000 steps at 512 px); not for a CPU",
    "demo": "600 steps at 96 px (about 40 s on 2 cores): to check that everything runs",
}
PRESET_ITEMS = [(name, name, PRESET_HELP.get(name, "")) for name in PRESETS]


def time_limit_property(description: str):
    """Minutes a run may take, its steps shortened to fit (train/time_limit.py); 0: none."""
    return bpy.props.FloatProperty(
        name="Time limit (min)", min=0.0, soft_max=600.0, default=0.0, description=description
    )


def _show_preset(self, context):
    """Choosing a preset shows its values (they are then what trains)."""
    values = config_data(self.preset)
    for name in OVERRIDABLE:
        setattr(self, name, values[name])


def _tracked_folder(head) -> Path | None:
    """The tracker's folder the head was imported from (frames/ beside tracking.npz)."""
    sequence = head.get("archhead_sequence") if head is not None else None
    if not sequence:
        return None
    folder = Path(bpy.path.abspath(sequence)).parent
    ok = Path(sequence).name == TRACKING_FILE and (folder / FRAMES_DIR).is_dir()
    return folder if ok else None


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
    # declared before the fields it fills in: Blender applies an operator's given properties
    # in declaration order, so a script's explicit resolution or steps win
    preset: bpy.props.EnumProperty(
        name="Preset",
        items=PRESET_ITEMS,
        default=DEFAULT_PRESET,
        update=_show_preset,
    )
    resolution: bpy.props.IntProperty(name="Resolution", min=32, default=PRESET["resolution"])
    stage1_steps: bpy.props.IntProperty(name="Stage 1 steps", min=0, default=PRESET["stage1_steps"])
    stage2_steps: bpy.props.IntProperty(name="Stage 2 steps", min=0, default=PRESET["stage2_steps"])
    minutes: time_limit_property(
        "Finish within this many minutes, every stage's steps shortened in one proportion "
        "(0: the steps above, however long they take); with Resume, counted from now"
    )
    resume: bpy.props.BoolProperty(name="Resume", description="Continue the run in Output")
    base_config: bpy.props.StringProperty(
        name="Base config",
        subtype="FILE_PATH",
        description="Optional training config (JSON) in place of the preset; the fields "
        "above override its values where you changed them",
    )

    def invoke(self, context, event):
        last = STATE.dialog_fields.get(DIALOG_KEY)
        if last:
            for name, value in last.items():
                setattr(self, name, value)
        else:
            folder = _tracked_folder(head_of(context.active_object))
            if folder is not None:
                self.frames_dir = str(folder / FRAMES_DIR)
                self.tracking = str(folder / TRACKING_FILE)
                self.out_dir = str(folder.parent / f"{folder.name}_avatar")
        return context.window_manager.invoke_props_dialog(self, width=480)

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        for name in ("frames_dir", "tracking", "out_dir", "preset"):
            layout.prop(self, name)
        column = layout.column(align=True)
        for name in OVERRIDABLE:
            column.prop(self, name)
        layout.prop(self, "minutes")
        layout.prop(self, "resume")
        layout.prop(self, "base_config")

    def execute(self, context):
        head = head_of(context.active_object)
        self.remember()
        try:
            frames_dir, tracking, out_dir = self.paths()
            settings = training_settings(
                self.overrides(),
                bpy.path.abspath(self.base_config) if self.base_config else self.preset,
            )
            self.run = start_training(
                context,
                frames_dir,
                tracking,
                out_dir,
                settings,
                self.resume,
                head.name if head else None,
                minutes=self.minutes,
            )
        except (InputError, OSError, ValueError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        return self.watch(context)

    def paths(self) -> tuple[str, str, str]:
        """Frames, tracking and output as absolute paths; empty fields are named (an empty
        path would otherwise mean Blender's current folder)."""
        if not self.frames_dir.strip():
            raise ValueError("Frames: choose the folder of video frames (Track Video makes one)")
        frames_dir = Path(bpy.path.abspath(self.frames_dir))
        tracking = self.tracking.strip()
        if not tracking and (frames_dir.parent / TRACKING_FILE).is_file():
            tracking = str(frames_dir.parent / TRACKING_FILE)  # the tracker's own folder
        if not tracking:
            raise ValueError(f"Tracking: choose the tracking file of {frames_dir}")
        if not self.out_dir.strip():
            raise ValueError("Output: choose a folder for the run (it is created)")
        return str(frames_dir), bpy.path.abspath(tracking), bpy.path.abspath(self.out_dir)

    def remember(self) -> None:
        """The fields the user set, for the next time the dialog opens."""
        STATE.dialog_fields[DIALOG_KEY] = self.fields_set((*REMEMBERED, *OVERRIDABLE))

    def overrides(self) -> dict:
        """The fields the user (or a script) set; the rest come from the base config."""
        return self.fields_set(OVERRIDABLE)

    def fields_set(self, names) -> dict:
        return {n: getattr(self, n) for n in names if self.properties.is_property_set(n)}

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
