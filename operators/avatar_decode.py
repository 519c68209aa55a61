"""Decode Frames: the frame sets of the selected avatars (the active head's at least) into the
caches, one scene frame per timer tick for all of them, so the interface stays live, shows
progress (cursor, status bar, N-panel) and stops on Esc or the panel's Cancel. The work is
archhead_blender.decoding's.

Decoding is an undo step of its own (a cancelled decode too, once it kept a frame): without
one, Ctrl+Z right after it would go back past Load Avatar, and Ctrl+Shift+Z would bring the
avatar back without its decoded frames. The decoded frames are a cache of the session, not scene
data: undoing the step keeps them (the avatar object, and with it its session, stays)."""

from __future__ import annotations

import bpy

from archhead_addon.io.errors import InputError
from archhead_blender.avatar_objects import active_avatar, selected_avatars
from archhead_blender.avatar_session import session
from archhead_blender.decoding import decode_frame, decode_frames, scene_plan
from archhead_blender.handlers import refresh_scene, resume, suspend
from archhead_blender.state import STATE


class ARCHHEAD_OT_decode_avatar(bpy.types.Operator):
    """Decode the selected avatars' frames (keyed, all or every n-th) into the cache; Esc cancels"""

    bl_idname = "archhead.decode_avatar"
    bl_label = "Decode Frames"
    bl_options = {"UNDO"}

    @classmethod
    def poll(cls, context):
        return active_avatar(context) is not None

    def execute(self, context):
        objs = selected_avatars(context)
        try:
            count = decode_frames(context, objs)
        except (InputError, OSError, ValueError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"Decoded {count} frames")
        return {"FINISHED"}

    def invoke(self, context, event):
        if bpy.app.background:  # no event loop to drive a modal operator
            return self.execute(context)
        self.objs = selected_avatars(context)
        try:
            for obj in self.objs:
                session(obj).decoded.clear()
        except (InputError, OSError, ValueError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.plan = scene_plan(context.scene, self.objs)
        if not self.plan:
            self.report({"WARNING"}, "No frames to decode in the scene's frame range")
            return {"CANCELLED"}
        self.start = context.scene.frame_current
        self.uids = [obj.session_uid for obj in self.objs]
        progress = {"done": 0, "total": len(self.plan), "cancel": False}
        for uid in self.uids:  # one record: the panel of any of them shows it
            STATE.decode_progress[uid] = progress
        self.progress = progress
        wm = context.window_manager
        wm.progress_begin(0, max(len(self.plan), 1))
        self.timer = wm.event_timer_add(0.001, window=context.window)
        wm.modal_handler_add(self)
        suspend()
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        state = self.progress
        if any(STATE.decode_progress.get(uid) is not state for uid in self.uids):
            # an avatar was deleted (prune_sessions forgot its progress)
            return self._finish(context, None, alive=False)
        if event.type == "ESC" or state["cancel"]:
            return self._finish(context, f"Cancelled after {state['done']} frames")
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        try:
            frame, members = self.plan[state["done"]]
            decode_frame(context, members, frame)
        except (InputError, OSError, ValueError) as exc:
            self.report({"ERROR"}, str(exc))
            return self._finish(context, None)
        state["done"] += 1
        context.window_manager.progress_update(state["done"])
        text = f"ArchHead: decoded {state['done']} / {state['total']} frames (Esc cancels)"
        if context.workspace is not None:
            context.workspace.status_text_set(text)
        _redraw_sidebars(context)
        if state["done"] == state["total"]:
            return self._finish(context, f"Decoded {state['total']} frames")
        return {"RUNNING_MODAL"}

    def _finish(self, context, message, alive: bool = True):
        wm = context.window_manager
        wm.event_timer_remove(self.timer)
        wm.progress_end()
        if context.workspace is not None:
            context.workspace.status_text_set(None)
        for uid in self.uids:
            STATE.decode_progress.pop(uid, None)
        context.scene.frame_set(self.start)
        resume()
        kept = False
        if alive:
            refresh_scene(context.scene, context.evaluated_depsgraph_get())
            kept = any(session(obj).decoded for obj in self.objs)
        _redraw_sidebars(context)
        if message:
            self.report({"INFO"}, message)
        # FINISHED makes the undo step: a decode that kept frames, cancelled or not
        return {"FINISHED"} if kept and message else {"CANCELLED"}


class ARCHHEAD_OT_cancel_decode(bpy.types.Operator):
    """Stop decoding after the current frame"""

    bl_idname = "archhead.cancel_decode"
    bl_label = "Cancel Decoding"
    bl_options = {"INTERNAL"}

    def execute(self, context):
        for state in STATE.decode_progress.values():
            state["cancel"] = True
        return {"FINISHED"}


def _redraw_sidebars(context) -> None:
    screen = context.screen
    for area in screen.areas if screen else ():
        if area.type == "VIEW_3D":
            area.tag_redraw()
