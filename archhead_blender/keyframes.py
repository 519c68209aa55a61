"""Bulk keyframing that works on Blender 4.2 through 5.0.

Blender 4.4 introduced slotted actions and 5.0 removed `Action.fcurves`: there F-curves live
in a channelbag of a keyframe strip, per slot. Keys go in with `keyframe_points.add` +
`foreach_set`, never one `keyframe_insert` per key.
"""

from __future__ import annotations

import bpy
import numpy as np


def _channelbag(action, slot):
    """The channelbag holding `slot`'s F-curves (Blender 4.4+ layered actions)."""
    if not action.layers:
        action.layers.new("Layer")
    layer = action.layers[0]
    if not layer.strips:
        layer.strips.new(type="KEYFRAME")
    return layer.strips[0].channelbag(slot, ensure=True)


class ActionWriter:
    """Creates an action for one ID and writes whole F-curves into it."""

    def __init__(self, id_data, name: str):
        self.id_data = id_data
        self.action = bpy.data.actions.new(name)
        anim = id_data.animation_data or id_data.animation_data_create()
        anim.action = self.action
        self._fcurves = None
        if not hasattr(self.action, "fcurves"):  # Blender 5.0: channelbags only
            slot = self.action.slots.new(id_type=id_data.id_type, name=id_data.name)
            anim.action_slot = slot
            self._fcurves = _channelbag(self.action, slot).fcurves

    def fcurves(self):
        return self._fcurves if self._fcurves is not None else self.action.fcurves

    def write(
        self,
        data_path: str,
        frames: np.ndarray,
        values: np.ndarray,
        index: int = 0,
        group: str | None = None,
        interpolation: str = "LINEAR",
    ):
        """One F-curve with a key at every (frame, value); values (T,)."""
        fcurves = self.fcurves()
        if self._fcurves is None and group:  # classic API takes the group name directly
            fc = fcurves.new(data_path, index=index, action_group=group)
        else:
            fc = fcurves.new(data_path, index=index)
        n = len(frames)
        fc.keyframe_points.add(n)
        co = np.empty((n, 2), dtype=np.float32)
        co[:, 0], co[:, 1] = frames, values
        fc.keyframe_points.foreach_set("co", co.ravel())
        mode = bpy.types.Keyframe.bl_rna.properties["interpolation"].enum_items[interpolation].value
        fc.keyframe_points.foreach_set("interpolation", np.full(n, mode, dtype=np.int32))
        fc.update()
        return fc

    def write_vector(
        self, data_path: str, frames: np.ndarray, values: np.ndarray, group: str | None = None
    ):
        """One F-curve per column of values (T,C)."""
        for i in range(values.shape[1]):
            self.write(data_path, frames, values[:, i], index=i, group=group)
