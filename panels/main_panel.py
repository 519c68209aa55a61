"""The ArchHead tab of the 3D view's sidebar."""

import bpy

from archhead_blender.avatar_objects import avatar_of, head_of
from archhead_blender.features import missing_kernel
from archhead_blender.preferences import get_preferences
from archhead_blender.state import STATE
from archhead_blender.tracking import current_tracking
from archhead_blender.training import current_run
from archhead_blender.video_avatar import current_video_run


class ARCHHEAD_PT_main(bpy.types.Panel):
    bl_label = "ArchHead"
    bl_idname = "ARCHHEAD_PT_main"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "ArchHead"

    def draw(self, context):
        layout = self.layout
        prefs = get_preferences(context)
        model = (prefs.flame_model_path if prefs else "") or "built-in"
        layout.label(text=f"Model: {bpy.path.basename(model) or model}", icon="MESH_MONKEY")
        layout.operator("archhead.import_sequence", icon="IMPORT")
        if current_video_run() is not None:  # its stage's tracking or training run inside
            _draw_video_avatar(layout, current_video_run())
        else:
            layout.operator("archhead.avatar_from_video", icon="OUTLINER_OB_CAMERA")
            _draw_tracking(layout)
            _draw_training(layout, context)
        missing = missing_kernel()
        if missing:
            layout.label(text=missing, icon="INFO")
        head = head_of(context.active_object)
        if head is None:
            layout.label(text="No imported head selected")
            return
        box = layout.box()
        box.label(text=head.name, icon="OUTLINER_OB_ARMATURE")
        box.label(
            text=f"Frames: {head.get('archhead_frames', '?')}  "
            f"fps: {head.get('archhead_source_fps', 0):g}"
        )
        box.label(text=f"Format: {head.get('archhead_format', '?')}")
        box.label(text=f"Expressions: {head.get('archhead_n_expr', 0)}")
        _draw_avatar(layout, context, head)


def _draw_avatar(layout, context, head):
    box = layout.box()
    obj = avatar_of(head)
    if obj is None:
        box.operator("archhead.load_avatar", icon="SHADING_RENDERED")
        return
    settings = obj.archhead_avatar
    # one fact a line: the default sidebar width cut "name: N Gaussians" off
    box.label(text=obj.name, icon="POINTCLOUD_DATA")
    box.label(text=f"{len(obj.data.vertices):,} Gaussians")
    box.label(text=bpy.path.basename(settings.checkpoint), icon="FILE")
    if obj.session_uid in STATE.errors:
        box.label(text=STATE.errors[obj.session_uid], icon="ERROR")
    box.prop(settings, "lod", slider=True)
    box.operator("archhead.drive_lod", icon="DRIVER")
    col = box.column(align=True)
    col.prop(settings, "decode_frames")
    if settings.decode_frames == "STRIDE":
        col.prop(settings, "stride")
    col.label(text="Between decoded frames:")
    col.prop(settings, "between", text="")
    state = STATE.decode_progress.get(obj.session_uid)
    if state is None:
        box.operator("archhead.decode_avatar", icon="RENDER_ANIMATION")
    else:
        row = box.row()
        row.progress(
            factor=state["done"] / max(state["total"], 1),
            text=f"Decoding {state['done']} / {state['total']}",
        )
        row.operator("archhead.cancel_decode", text="", icon="CANCEL")
    col = box.column(align=True)
    col.prop(settings, "view_dependent")
    col.prop(settings, "cull")
    col.prop(settings, "identity")
    col.prop(settings, "disk_cache")
    if settings.disk_cache:
        col.prop(settings, "cache_dir", text="")
    box.operator("archhead.export_ply", icon="EXPORT")
    box.operator("archhead.load_avatar", text="Replace Checkpoint", icon="FILE_REFRESH")
    crowd = layout.box()  # the scene's, for every avatar in it
    crowd.label(text="All avatars", icon="COMMUNITY")
    col = crowd.column(align=True)
    col.prop(context.scene.archhead_crowd, "lod_bias", slider=True)
    col.prop(context.scene.archhead_crowd, "gaussian_budget")


def _draw_video_avatar(layout, run):
    """Avatar from Video: one bar over its stages (tracking, then training)."""
    box = layout.box()
    box.label(text="Avatar from Video", icon="OUTLINER_OB_CAMERA")
    box.label(text=run.step_text())
    box.progress(factor=run.fraction, text=run.bar_text())
    detail = run.detail_text()
    if detail:
        box.label(text=detail)
    box.operator("archhead.cancel_video_avatar", text="Cancel", icon="CANCEL")
    col = box.column(align=True)
    col.label(text="Run it again on the same", icon="INFO")
    col.label(text="Output to go on after a stop", icon="BLANK1")


def _draw_tracking(layout):
    run = current_tracking()
    if run is None:
        layout.operator("archhead.track_video", icon="FILE_MOVIE")
        return
    box = layout.box()
    box.label(text="Tracking", icon="FILE_MOVIE")
    box.progress(factor=run.fraction, text=run.summary())
    box.operator("archhead.cancel_tracking", icon="CANCEL")


def _draw_training(layout, context):
    run = current_run()
    if run is None:
        layout.operator("archhead.train_avatar", icon="EXPERIMENTAL")
        return
    box = layout.box()
    box.label(text="Training", icon="EXPERIMENTAL")
    # short lines: the default sidebar width holds about 32 characters (the status bar has
    # the whole summary on one line)
    box.progress(factor=run.fraction, text=run.bar_text())
    rate = run.rate_text()
    if rate:
        box.label(text=rate)
    lines = run.loss_lines()
    if lines:
        col = box.column(align=True)
        for line in lines:
            col.label(text=line)
    row = box.row()
    row.operator("archhead.cancel_training", icon="CANCEL")
    col = box.column(align=True)
    col.label(text="Quitting stops it too", icon="INFO")
    col.label(text="(it saves first); Train", icon="BLANK1")
    col.label(text="Avatar > Resume goes on", icon="BLANK1")
