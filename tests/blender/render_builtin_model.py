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
import mathutils
import numpy as np

from archhead_addon.camera import FLAME_TO_BLENDER
from archhead_addon.flame.builtin import EXPRESSION_NAMES, builtin_model
from archhead_addon.flame.lbs import forward
from archhead_addon.flame.teeth import add_teeth

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


def _reset_scene(resolution: int, samples: int, transparent: bool):
    import _cycles  # Cycles' own module, importable once bpy is loaded

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = samples > 4 and _cycles.with_openimagedenoise
    scene.render.threads_mode = "FIXED"
    scene.render.threads = 2
    scene.render.resolution_x = scene.render.resolution_y = resolution
    scene.render.film_transparent = transparent
    scene.view_settings.view_transform = "Standard"
    world = bpy.data.worlds.new("world")
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.16, 0.17, 0.19, 1)
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.35
    scene.world = world
    return scene


def _image(albedo: np.ndarray):
    h, w, _ = albedo.shape
    image = bpy.data.images.new("albedo", w, h, alpha=False)
    rgba = np.concatenate([albedo[::-1] / 255.0, np.ones((h, w, 1))], axis=2)  # bottom row first
    image.pixels.foreach_set(rgba.astype(np.float32).ravel())
    image.pack()
    return image


def _material(name: str, image, roughness: tuple, subsurface: float):
    """Principled BSDF with the albedo as base colour; roughness runs from roughness[0] on
    the darkest texels (hair, brows) to roughness[1] on the brightest."""
    mat = bpy.data.materials.new(name)
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = nodes["Principled BSDF"]
    bsdf.inputs["Specular IOR Level"].default_value = 0.4
    bsdf.inputs["Subsurface Weight"].default_value = subsurface
    bsdf.inputs["Subsurface Radius"].default_value = (0.004, 0.0015, 0.001)
    bsdf.inputs["Subsurface Scale"].default_value = 1.0
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = image
    links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    grey, rough = nodes.new("ShaderNodeRGBToBW"), nodes.new("ShaderNodeMapRange")
    rough.inputs["To Min"].default_value, rough.inputs["To Max"].default_value = roughness
    rough.inputs["From Max"].default_value = 0.6
    links.new(tex.outputs["Color"], grey.inputs["Color"])
    links.new(grey.outputs["Val"], rough.inputs["Value"])
    links.new(rough.outputs["Result"], bsdf.inputs["Roughness"])
    return mat


def add_head(model, verts: np.ndarray):
    """A smooth-shaded mesh object of the head in Blender's z-up world, textured."""
    mesh = bpy.data.meshes.new("head")
    mesh.from_pydata(verts.tolist(), [], model.faces.tolist())
    mesh.uv_layers.new(name="UVMap").data.foreach_set(
        "uv", model.uv[model.uv_faces].astype(np.float32).ravel())
    mesh.shade_smooth()
    image = _image(model.albedo)
    mesh.materials.append(_material("skin", image, roughness=(0.85, 0.5), subsurface=0.15))
    mesh.materials.append(_material("eyes", image, roughness=(0.08, 0.08), subsurface=0.0))
    on_eyes = (model.weights[model.faces][..., 3:].sum(-1) > 0.999).all(1)
    mesh.polygons.foreach_set("material_index", on_eyes.astype(np.int32))
    obj = bpy.data.objects.new("head", mesh)
    obj.matrix_world = mathutils.Matrix(FLAME_TO_BLENDER.tolist())
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _look_at(obj, target):
    """Point the object's local -Z (cameras, lights) at `target`, +Y up."""
    direction = np.asarray(target) - np.asarray(obj.location)
    obj.rotation_euler = (np.arctan2(np.hypot(direction[0], direction[1]), -direction[2]), 0,
                          np.arctan2(direction[1], direction[0]) - np.pi / 2)


def _flame_point(p):
    return (FLAME_TO_BLENDER[:3, :3] @ np.asarray(p, float)).tolist()


def add_camera_and_lights(target_flame=(0.0, -0.004, 0.02)):
    """A camera at CAMERA_YAW looking at the face, and key, fill and rim area lights."""
    scene = bpy.context.scene
    target = _flame_point(target_flame)
    cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    cam.data.lens = 100
    distance = 0.88
    cam.location = _flame_point([distance * np.sin(CAMERA_YAW), 0.0,
                                 distance * np.cos(CAMERA_YAW)])
    _look_at(cam, target)
    scene.collection.objects.link(cam)
    scene.camera = cam
    for name, pos, power, size in (("key", (0.55, 0.45, 0.7), 20.0, 0.5),
                                   ("fill", (-0.7, 0.05, 0.55), 7.0, 0.8),
                                   ("rim", (0.1, 0.5, -0.8), 20.0, 0.4)):
        light = bpy.data.objects.new(name, bpy.data.lights.new(name, "AREA"))
        light.data.energy, light.data.size = power, size
        light.location = _flame_point(pos)
        _look_at(light, target)
        scene.collection.objects.link(light)


def render_pose(model, pose: dict, path, resolution=512, samples=24, transparent=False):
    """Render one pose of the model to an image file."""
    scene = _reset_scene(resolution, samples, transparent)
    add_head(model, pose_vertices(model, pose))
    add_camera_and_lights()
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
