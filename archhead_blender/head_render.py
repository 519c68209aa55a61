"""Cycles scene pieces for rendering a FLAME-format head: textured mesh, light rig, cameras.

Shared by the synthetic subject (`synthetic_subject.py`) and the documentation renders
(`tests/blender/render_builtin_model.py`); no operator uses them. Never imports torch.
"""

from __future__ import annotations

import bpy
import mathutils
import numpy as np

from archhead_addon.camera import (
    FLAME_TO_BLENDER,
    intrinsics_to_blender,
    w2c_to_blender_matrix_world,
)
from archhead_addon.threads import thread_count

from .compat import ensure_node_tree

# key, fill and rim area lights: position in FLAME space (metres), power (W), size (m)
LIGHT_RIG = (
    ("key", (0.55, 0.45, 0.7), 20.0, 0.5),
    ("fill", (-0.7, 0.05, 0.55), 7.0, 0.8),
    ("rim", (0.1, 0.5, -0.8), 20.0, 0.4),
)
FACE_CENTRE = (0.0, -0.004, 0.02)  # FLAME space; where the lights point


def reset_scene(resolution: int, samples: int, transparent: bool, threads: int = 0):
    """An empty Cycles (CPU) scene: square `resolution`, `samples` per pixel (denoised above
    4 when OpenImageDenoise is built in), Standard view transform (sRGB, no tone curve),
    `threads` render threads (0: all cores); a dim grey world that also lights the head."""
    import _cycles  # Cycles' own module, importable once bpy is loaded

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = samples > 4 and _cycles.with_openimagedenoise
    scene.render.threads_mode = "FIXED" if threads else "AUTO"
    scene.render.threads = thread_count(threads, "render settings", "threads") if threads else 1
    scene.render.resolution_x = scene.render.resolution_y = resolution
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = transparent
    scene.view_settings.view_transform = "Standard"
    world = bpy.data.worlds.new("world")
    background = ensure_node_tree(world).nodes["Background"]
    background.inputs["Color"].default_value = (0.16, 0.17, 0.19, 1)
    background.inputs["Strength"].default_value = 0.35
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
    nodes, links = ensure_node_tree(mat).nodes, mat.node_tree.links
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
    """A smooth-shaded mesh object of the head (FLAME-space vertices, placed in Blender's
    z-up world by FLAME_TO_BLENDER), textured with the model's UVs and albedo; glossy eyes."""
    mesh = bpy.data.meshes.new("head")
    mesh.from_pydata(verts.tolist(), [], model.faces.tolist())
    mesh.uv_layers.new(name="UVMap").data.foreach_set(
        "uv", model.uv[model.uv_faces].astype(np.float32).ravel()
    )
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


def set_vertices(obj, verts: np.ndarray) -> None:
    """Move the head's vertices (FLAME space, same order as the model's); normals follow."""
    mesh = obj.data
    mesh.vertices.foreach_set("co", np.asarray(verts, dtype=np.float32).ravel())
    mesh.update()


def look_at(obj, target) -> None:
    """Point the object's local -Z (cameras, lights) at `target`, +Y up (Blender world)."""
    direction = np.asarray(target) - np.asarray(obj.location)
    obj.rotation_euler = (
        np.arctan2(np.hypot(direction[0], direction[1]), -direction[2]),
        0,
        np.arctan2(direction[1], direction[0]) - np.pi / 2,
    )


def flame_point(p) -> list[float]:
    """A FLAME-space point in Blender's world."""
    return (FLAME_TO_BLENDER[:3, :3] @ np.asarray(p, float)).tolist()


def add_lights(target_flame=FACE_CENTRE) -> None:
    """The LIGHT_RIG, each area light aimed at `target_flame`."""
    scene = bpy.context.scene
    target = flame_point(target_flame)
    for name, pos, power, size in LIGHT_RIG:
        light = bpy.data.objects.new(name, bpy.data.lights.new(name, "AREA"))
        light.data.energy, light.data.size = power, size
        light.location = flame_point(pos)
        look_at(light, target)
        scene.collection.objects.link(light)


def add_opencv_camera(K, w2c, width: int, height: int):
    """The scene camera projecting like OpenCV K, w2c (FLAME world) at width x height."""
    scene = bpy.context.scene
    params = intrinsics_to_blender(K, width, height)
    data = bpy.data.cameras.new("camera")
    data.sensor_fit = "HORIZONTAL"
    data.sensor_width, data.lens = params.sensor_width, params.lens
    data.shift_x, data.shift_y = params.shift_x, params.shift_y
    data.clip_start, data.clip_end = 0.01, 100.0
    render = scene.render
    render.resolution_x, render.resolution_y = params.resolution_x, params.resolution_y
    render.pixel_aspect_x, render.pixel_aspect_y = params.pixel_aspect_x, params.pixel_aspect_y
    cam = bpy.data.objects.new("camera", data)
    cam.matrix_world = mathutils.Matrix(w2c_to_blender_matrix_world(w2c).tolist())
    scene.collection.objects.link(cam)
    scene.camera = cam
    return cam
