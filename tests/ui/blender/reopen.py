"""The saved scene opened in a new window (blender SCENE.blend --python reopen.py): the
add-on's handlers are attached, the avatar shows the frame and follows the timeline and
the LOD driver; then the add-on disabled and enabled again, and the driver still works.

    blender scene.blend --python reopen.py -- HEAD_NAME
"""

import sys
from pathlib import Path

import bpy

sys.path.insert(0, str(Path(__file__).resolve().parent))
import ui_steps  # noqa: E402
from ui_driver import check, run_steps, script_args  # noqa: E402

HEAD = script_args()[0]
ADDON = "bl_ext.user_default.archhead"


def handlers(ui):
    names = {
        kind: [f.__name__ for f in getattr(bpy.app.handlers, kind)]
        for kind in ("frame_change_post", "depsgraph_update_post", "load_post")
    }
    ui.data["handlers"] = names
    check("on_frame_change" in names["frame_change_post"], f"no frame handler: {names}")
    check("on_depsgraph_update" in names["depsgraph_update_post"], f"no update handler: {names}")


def follows_timeline(ui):
    avatar = bpy.data.objects[f"{HEAD}_avatar"]
    scene = bpy.context.scene
    head = avatar.archhead_avatar.head
    check(head.show_only_shape_key, "the head's Basis shape is not pinned under its avatar")
    expressions = []
    for frame in (scene.frame_start + 2, scene.frame_end - 2):
        scene.frame_set(frame)
        yield from ui.wait_until(
            lambda: ui_steps.shows_lod(avatar, ui_steps.evaluated_lod(avatar)),
            10,
            f"the avatar at frame {frame}",
        )
        expressions.append(ui_steps.avatar_codes(avatar).expr)
    # the pinned head's keys still drive the avatar: its expression codes follow the timeline
    change = float(abs(expressions[1] - expressions[0]).max())
    ui.data["expression_change"] = change
    check(change > 1e-3, f"the expression codes did not follow the timeline: {change}")
    yield from ui.show_sidebar()
    ui.screenshot("reopened")


def disable_enable(ui):
    with ui.context(None):
        bpy.ops.preferences.addon_disable(module=ADDON)
    yield 0.5
    with ui.context(None):
        bpy.ops.preferences.addon_enable(module=ADDON)
    yield 0.5
    avatar = bpy.data.objects[f"{HEAD}_avatar"]
    scene = bpy.context.scene
    driver = avatar.animation_data.drivers[0]
    check(driver.driver.is_valid, "the LOD driver is invalid after disable / enable")
    lods = []
    for frame in (scene.frame_start, scene.frame_end):
        scene.frame_set(frame)
        yield 0.3
        lods.append(ui_steps.evaluated_lod(avatar))
        yield from ui.wait_until(
            lambda: ui_steps.shows_lod(avatar, ui_steps.evaluated_lod(avatar)),
            10,
            f"the avatar at frame {frame} after enable",
        )
    ui.data["lods_after_enable"] = lods
    check(lods[0] > lods[1] + 0.3, f"the driver did not follow the camera: {lods}")


run_steps(
    [
        ("handlers attached", handlers),
        ("avatar follows the timeline", follows_timeline),
        ("disable and enable the add-on", disable_enable),
    ]
)
