"""Drive the level of detail by the distance from the scene camera to the head.

The driver is a simple expression (Blender evaluates it without Python, so it runs in files
whose scripts are not trusted and in background renders): a LOC_DIFF distance `d` between
the camera and the head's root bone, and `near` / `far` read from custom properties of the
avatar object, so they can be changed (or animated) without editing the expression, plus
the scene's LOD bias (`Scene.archhead_crowd.lod_bias`), one slider for every driven avatar.
By distance the level grows linearly from `near` to `far`. By screen size it follows the
head's size in the image: the UV resolution falls as 1 / distance, the distance taken
through the lens (times 50 mm over the focal length, so a head zoomed in on keeps its
detail), which keeps the Gaussians per pixel of the head the same from `near` to `far`.
The camera targets follow the scene's active camera (`follow_scene_camera`, run by the
handlers): a camera made active by hand or by a camera marker drives the level of detail.
"""

from __future__ import annotations

import bpy

from .scene_state import head_rig

DRIVER_EXPRESSION = "min(max((d - near) / (far - near) + bias, 0), 1)"
# l = (1 - near / d') / (1 - near / far), d' = d * 50 / lens: the UV resolution falls as the
# head's size on screen, S = S_max near / d', from S_max at `near` to S_max near / far at
# `far` (with far = near S_max / S_min, S_min there: Gaussians per pixel stay the same)
SCREEN_EXPRESSION = (
    "min(max((1 - near * lens / (max(d, 0.001) * 50)) / (1 - near / far) + bias, 0), 1)"
)
NEAR_PROP, FAR_PROP = "archhead_lod_near", "archhead_lod_far"
LOD_PATH = "archhead_avatar.lod"
BIAS_PATH = "archhead_crowd.lod_bias"  # on the scene (crowd.py)
MODES = ("DISTANCE", "SCREEN")


def drive_lod_by_distance(obj, camera, near: float, far: float, mode: str = "DISTANCE"):
    """Replace any animation of the avatar's level of detail with the distance driver
    (`mode` "SCREEN": the distance as seen through the camera's lens, module docstring)."""
    if not far > near:
        raise ValueError(f"far ({far}) must be greater than near ({near})")
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    obj[NEAR_PROP], obj[FAR_PROP] = float(near), float(far)
    for prop in (NEAR_PROP, FAR_PROP):
        obj.id_properties_ui(prop).update(
            min=0.0,
            subtype="DISTANCE",
            description="Camera distance mapped to LOD 0 (near) or LOD 1 (far)",
        )
    obj.driver_remove(LOD_PATH)
    driver = obj.driver_add(LOD_PATH).driver
    driver.type = "SCRIPTED"
    distance = driver.variables.new()
    distance.name, distance.type = "d", "LOC_DIFF"
    cam_target, head_target = distance.targets
    cam_target.id = camera
    head_target.id = head_rig(obj.archhead_avatar.head)
    head_target.bone_target = "global"
    for target in distance.targets:
        target.transform_space = "WORLD_SPACE"
    for name, prop in (("near", NEAR_PROP), ("far", FAR_PROP)):
        var = driver.variables.new()
        var.name, var.type = name, "SINGLE_PROP"
        var.targets[0].id_type = "OBJECT"
        var.targets[0].id = obj
        var.targets[0].data_path = f'["{prop}"]'
    bias = driver.variables.new()
    bias.name, bias.type = "bias", "SINGLE_PROP"
    bias.targets[0].id_type = "SCENE"
    bias.targets[0].id = obj.users_scene[0] if obj.users_scene else bpy.context.scene
    bias.targets[0].data_path = BIAS_PATH
    if mode == "SCREEN":
        lens = driver.variables.new()
        lens.name, lens.type = "lens", "SINGLE_PROP"
        lens.targets[0].id_type = "CAMERA"
        lens.targets[0].id = camera.data
        lens.targets[0].data_path = "lens"
    driver.expression = SCREEN_EXPRESSION if mode == "SCREEN" else DRIVER_EXPRESSION
    driver.use_self = False
    return driver


def follow_scene_camera(obj, scene) -> bool:
    """Point the avatar's distance driver at the scene's active camera; True if it moved."""
    drivers = obj.animation_data.drivers if obj.animation_data else None
    curve = drivers.find(LOD_PATH) if drivers is not None else None
    camera = scene.camera
    if curve is None or camera is None:
        return False
    variables = curve.driver.variables
    distance, lens = variables.get("d"), variables.get("lens")
    moved = False
    if distance is not None and distance.type == "LOC_DIFF" and distance.targets[0].id != camera:
        distance.targets[0].id = camera
        moved = True
    if lens is not None and camera.type == "CAMERA" and lens.targets[0].id != camera.data:
        lens.targets[0].id = camera.data
        moved = True
    return moved
