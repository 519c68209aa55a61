"""Render the built-in head model with Blender Cycles (the pictures in docs/).

    .venv/bin/python tests/blender/render_builtin_model.py --out docs/

Poses the model (with teeth) with the numpy FLAME forward pass, builds a mesh with the
model's own UVs and albedo, and renders it under three lights. The test suite calls
`render_pose` at a tiny size to check that this keeps working.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import bpy
import numpy as np

from archhead_addon.flame.builtin import EXPRESSION_NAMES, builtin_model
from archhead_addon.flame.lbs import forward
from archhead_addon.flame.teeth import add_teeth
from archhead_blender.head_render import (
    add_head,
    add_lights,
    flame_point,
    look_at,
    reset_scene,
)

POSES = {  # file name -> FLAME codes
    "builtin_neutral": {},
    "builtin_smile": {"expr": {"smile": 1.0}},
    "builtin_jaw_open": {"jaw": [0.28, 0.0, 0.0], "expr": {"jaw_open": 0.6}},
    "builtin_eyes_turned": {"eyes": [-0.08, 0.45, 0.0, -0.08, 0.45, 0.0]},
}
CAMERA_YAW = np.radians(22.0)  # a three-quarter view from the subject's left


def pose_vertices(model, pose: dict) -> np.ndarray:
    """Posed vertices (V,3) for a POSES entry (expressions given by name)."""
    expr = np.zeros(model.n_expr)
    for name, value in pose.get("expr", {}).items():
        expr[EXPRESSION_NAMES.index(name)] = value
    codes = {k: np.asarray(v, float) for k, v in pose.items() if k != "expr"}
    return forward(model, expr=expr, **codes)[0]


def add_camera(target_flame=(0.0, -0.004, 0.02)):
    """A 100 mm camera at CAMERA_YAW, 0.88 m away, looking at the face."""
    scene = bpy.context.scene
    cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    cam.data.lens = 100
    distance = 0.88
    cam.location = flame_point([distance * np.sin(CAMERA_YAW), 0.0, distance * np.cos(CAMERA_YAW)])
    look_at(cam, flame_point(target_flame))
    scene.collection.objects.link(cam)
    scene.camera = cam


def render_pose(model, pose: dict, path, resolution=512, samples=24, transparent=False):
    """Render one pose of the model to an image file."""
    scene = reset_scene(resolution, samples, transparent)
    add_head(model, pose_vertices(model, pose))
    add_camera()
    add_lights()
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGBA" if transparent else "RGB"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs"))
    parser.add_argument("--resolution", type=int, default=512)
    parser.add_argument("--samples", type=int, default=24)
    parser.add_argument("--only", nargs="*", default=None, help="names from POSES")
    args = parser.parse_args(argv)
    model = add_teeth(builtin_model())
    args.out.mkdir(parents=True, exist_ok=True)
    for name, pose in POSES.items():
        if args.only and name not in args.only:
            continue
        start = time.perf_counter()
        render_pose(model, pose, args.out / f"{name}.png", args.resolution, args.samples)
        print(f"{name}.png: {time.perf_counter() - start:.1f} s")


if __name__ == "__main__":
    main()
