"""What Train Avatar and Track Video share: watching a backend process from a modal timer
(or waiting for it where there is no event loop) and reporting how it ended."""

from __future__ import annotations

import time

import bpy

from archhead_blender.training import POLL_S


class BackendWatch:
    """Mixin for a modal operator whose `self.run` has `update()` and `summary()`;
    subclasses give `status_prefix` and `finish_run(context) -> (report type, message)`,
    and may give `advance(context)` in place of `self.run.update()` (a run of several
    stages that needs the context to go from one to the next)."""

    status_prefix = "ArchHead"

    def advance(self, context) -> bool:
        """Read the run's progress; True once it is over."""
        return self.run.update()

    def watch(self, context):
        if bpy.app.background:  # `blender -b` or the bpy module: no event loop, wait here
            while not self.advance(context):
                time.sleep(POLL_S)
            return self._finish(context)
        wm = context.window_manager
        self.timer = wm.event_timer_add(POLL_S, window=context.window)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        done = self.advance(context)
        if context.workspace is not None:
            context.workspace.status_text_set(
                None if done else f"{self.status_prefix}: {self.run.summary()}"
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
            kind, message = self.finish_run(context)
        except (OSError, ValueError) as exc:  # InputError is a ValueError
            kind, message = "ERROR", str(exc)
        self.report({kind}, message)
        if kind == "INFO" and not bpy.app.background:
            # What the run added (a loaded avatar, an imported head) becomes an undo step:
            # without one, Ctrl+Z went back past it and Redo could not bring it back.
            bpy.ops.ed.undo_push(message=self.bl_label)
        return {"FINISHED"} if kind == "INFO" else {"CANCELLED"}
