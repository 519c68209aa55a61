"""Solid mode shows the avatar in its colour, not as grey blobs: an avatar of one known skin
colour in the default Solid shading (colour "Material"), its pixels found as what changes on
screen when it is hidden.

    blender --python solid_colour.py -- SEQUENCE.npz AVATAR.npz
"""

import sys
from pathlib import Path

import bpy

sys.path.insert(0, str(Path(__file__).resolve().parent))
import ui_steps  # noqa: E402
from ui_driver import check, run_steps, screen_pixels, script_args  # noqa: E402

SEQUENCE, AVATAR = (Path(p) for p in script_args()[:2])
HEAD = SEQUENCE.stem


def load(ui):
    ui.op("archhead.import_sequence", filepath=str(SEQUENCE))
    ui.op("archhead.load_avatar", filepath=str(AVATAR))
    avatar = bpy.data.objects[f"{HEAD}_avatar"]
    avatar.archhead_avatar.lod = 1.0  # software OpenGL draws LOD 0 slowly
    yield from ui.wait_until(lambda: ui_steps.shows_lod(avatar, 1.0), 10, "the points at LOD 1")
    _, space = ui.view3d()
    check(space.shading.type == "SOLID", f"the viewport starts in {space.shading.type}")
    check(space.shading.color_type == "MATERIAL", f"Solid colour is {space.shading.color_type}")
    bpy.data.objects["Cube"].hide_set(True)
    for obj in bpy.context.selected_objects:
        obj.select_set(False)
    avatar.select_set(True)
    ui.frame_selected()
    avatar.select_set(False)  # no selection outline over its colour
    yield 0.5
    ui.screenshot("solid_mode", area_type="VIEW_3D")


def avatar_pixels(ui):
    """The 3D view's pixels with the avatar shown and hidden: where they differ is the avatar."""
    import numpy as np

    avatar = bpy.data.objects[f"{HEAD}_avatar"]
    area, space = ui.view3d()
    space.overlay.show_overlays = False
    crop = (area.x, area.y, area.width, area.height)
    shots = {}
    for hidden in (False, True):
        avatar.hide_set(hidden)
        yield 0.5
        ui.redraw()
        yield 0.3
        shots[hidden] = screen_pixels(crop).astype(np.float64) / 255
    avatar.hide_set(False)
    space.overlay.show_overlays = True
    mask = np.abs(shots[False] - shots[True]).sum(-1) > 0.1
    check(mask.sum() > 2000, f"the avatar covers only {int(mask.sum())} pixels")
    r, g, b = (float(v) for v in np.median(shots[False][mask], axis=0))
    ui.data["solid_avatar"] = {"pixels": int(mask.sum()), "median_rgb": [r, g, b]}
    # the avatar is skin coloured (sRGB 0.85, 0.45, 0.25), lit by the studio light; grey
    # blobs have r = g = b
    check(r > g + 0.12 and g > b + 0.04, f"the avatar's pixels are not its colour: {r, g, b}")


run_steps([("import and load in Solid mode", load), ("the avatar's colour", avatar_pixels)])
