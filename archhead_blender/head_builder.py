"""Builds the imported head in the scene: mesh, armature, shape keys, drivers, camera.

Operators call `build_head`; everything it creates is tracked so a failure removes it all.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field

import bpy
import numpy as np
from mathutils import Matrix

from archhead_addon.camera import (
    FLAME_TO_BLENDER,
    intrinsics_to_blender,
    w2c_to_blender_matrix_world,
)
from archhead_addon.flame.model import JOINT_NAMES
from archhead_addon.rig import (
    POSE_FEATURE_EXPRESSIONS,
    continuous_quaternions,
    pose_corrective_names,
    rig_animation,
)

from .compat import ensure_node_tree
from .keyframes import ActionWriter

ALBEDO_DIGEST = "archhead_albedo"  # a skin material's custom property: its albedo's digest

BONE_LENGTH = 0.02  # metres; only the display length, rest frames stay axis-aligned


@dataclass
class ImportOptions:
    n_expr: int | None = None  # expression shape keys kept (None = all of the model's)
    pose_correctives: str = "DRIVERS"  # or "KEYFRAMES" (from the tracked rotations), "NONE"
    camera: bool = True
    fps: float | None = None  # scene fps (None = the sequence's)
    name: str = "ArchHead"


@dataclass
class _Created:
    ids: list = field(default_factory=list)

    def add(self, id_block):
        self.ids.append(id_block)
        return id_block

    def remove_all(self):
        for id_block in reversed(self.ids):
            collection = {
                bpy.types.Object: bpy.data.objects,
                bpy.types.Mesh: bpy.data.meshes,
                bpy.types.Armature: bpy.data.armatures,
                bpy.types.Camera: bpy.data.cameras,
                bpy.types.Material: bpy.data.materials,
                bpy.types.Image: bpy.data.images,
                bpy.types.Action: bpy.data.actions,
            }
            for cls, data in collection.items():
                if isinstance(id_block, cls):
                    data.remove(id_block)
                    break


def build_head(context, model, seq, options: ImportOptions, info: dict):
    """Create the rigged, shape-keyed, animated head; returns the armature object."""
    created = _Created()
    try:
        return _build(context, model, seq, options, info, created)
    except BaseException:
        created.remove_all()
        raise


def _build(context, model, seq, options, info, created):
    rig = rig_animation(model, seq, options.n_expr)
    scene = context.scene
    fps = options.fps or seq.fps
    frames = scene_frames(seq, fps)
    collection = scene.collection

    arm_data = created.add(bpy.data.armatures.new(f"{options.name}_rig"))
    arm_obj = created.add(bpy.data.objects.new(f"{options.name}_rig", arm_data))
    arm_obj.matrix_world = Matrix(FLAME_TO_BLENDER.tolist())
    collection.objects.link(arm_obj)
    _build_bones(context, arm_obj, model, rig.rest_joints)

    mesh = _build_mesh(model, rig.rest_vertices, options.name, created)
    head = created.add(bpy.data.objects.new(options.name, mesh))
    collection.objects.link(head)
    head.parent = arm_obj
    _skin(head, arm_obj, model)
    _shape_keys(head, rig, options)
    if options.pose_correctives == "DRIVERS":
        _pose_drivers(head, arm_obj)

    _animate_bones(arm_obj, rig, frames, created)
    _animate_shape_keys(head, rig, frames, options.pose_correctives == "KEYFRAMES", created)
    if options.camera and seq.K is not None and seq.w2c is not None:
        _build_camera(scene, seq, frames, options.name, created)

    scene.render.fps, scene.render.fps_base = _fps_fraction(fps)
    scene.frame_start, scene.frame_end = int(frames[0]), int(frames[-1])
    _store_codes(head, arm_obj, model, rig, seq, info)
    return arm_obj


def scene_frames(seq, fps: float) -> np.ndarray:
    """Scene frame of every sequence frame: keys sit at their time in the scene's fps."""
    times = (np.asarray(seq.frame_ids, dtype=np.float64) - seq.frame_ids[0]) / seq.fps
    return 1 + np.round(times * fps, 6)


def _fps_fraction(fps: float) -> tuple[int, float]:
    rounded = round(fps)
    if abs(fps - rounded) < 1e-6:
        return int(rounded), 1.0
    base = math.ceil(fps) / fps  # e.g. 29.97 -> 30 / 1.001
    return math.ceil(fps), base


def _build_bones(context, arm_obj, model, joints):
    view_layer = context.view_layer
    previous = view_layer.objects.active
    view_layer.objects.active = arm_obj
    bpy.ops.object.mode_set(mode="EDIT")
    try:
        bones = []
        for j, name in enumerate(JOINT_NAMES):
            bone = arm_obj.data.edit_bones.new(name)
            bone.head = joints[j].tolist()
            bone.tail = (joints[j] + (0, BONE_LENGTH, 0)).tolist()  # +y, roll 0: axis-aligned
            bone.roll = 0.0
            if model.parents[j] >= 0:
                bone.parent = bones[model.parents[j]]
            bones.append(bone)
    finally:
        bpy.ops.object.mode_set(mode="OBJECT")
        view_layer.objects.active = previous
    for pose_bone in arm_obj.pose.bones:
        pose_bone.rotation_mode = "QUATERNION"


def _build_mesh(model, rest_vertices, name, created):
    mesh = created.add(bpy.data.meshes.new(name))
    n_v, n_f = len(rest_vertices), len(model.faces)
    mesh.vertices.add(n_v)
    mesh.vertices.foreach_set("co", rest_vertices.astype(np.float32).ravel())
    mesh.loops.add(3 * n_f)
    mesh.loops.foreach_set("vertex_index", model.faces.astype(np.int32).ravel())
    mesh.polygons.add(n_f)
    mesh.polygons.foreach_set("loop_start", np.arange(0, 3 * n_f, 3, dtype=np.int32))
    mesh.polygons.foreach_set("loop_total", np.full(n_f, 3, dtype=np.int32))
    if model.uv is not None:
        layer = mesh.uv_layers.new(name="UVMap")
        layer.data.foreach_set("uv", model.uv[model.uv_faces].astype(np.float32).ravel())
    mesh.polygons.foreach_set("use_smooth", np.ones(n_f, dtype=bool))
    mesh.update(calc_edges=True)
    mesh.validate(clean_customdata=False)
    if model.albedo is not None and model.uv is not None:
        mesh.materials.append(_albedo_material(model.albedo, name, created))
    return mesh


def _albedo_material(albedo, name, created):
    """The skin material of this albedo: one per albedo in a file, shared by every head that
    has it (a crowd of heads of one model had each packed its own 1024² texture, 5 MB a
    head); found again by the albedo's digest."""
    digest = hashlib.sha1(np.ascontiguousarray(albedo)).hexdigest()[:16]
    for mat in bpy.data.materials:
        if mat.get(ALBEDO_DIGEST) == digest and mat.library is None:
            return mat
    h, w = albedo.shape[:2]
    image = created.add(bpy.data.images.new(f"{name}_albedo", w, h, alpha=False))
    rgba = np.ones((h, w, 4), dtype=np.float32)
    rgba[..., :3] = albedo[::-1] / 255.0  # Blender's pixel rows start at the bottom
    image.pixels.foreach_set(rgba.ravel())
    image.pack()
    mat = created.add(bpy.data.materials.new(f"{name}_skin"))
    mat[ALBEDO_DIGEST] = digest
    nodes = ensure_node_tree(mat).nodes
    bsdf = next(n for n in nodes if n.type == "BSDF_PRINCIPLED")
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = image
    mat.node_tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    bsdf.inputs["Roughness"].default_value = 0.55
    return mat


def _skin(head, arm_obj, model):
    """Vertex groups from the skinning weights; grouped by value so each add() is bulk."""
    weights = model.weights
    for j, name in enumerate(JOINT_NAMES):
        group = head.vertex_groups.new(name=name)
        column = weights[:, j]
        nonzero = np.flatnonzero(column > 0)
        values, inverse = np.unique(column[nonzero], return_inverse=True)
        order = np.argsort(inverse, kind="stable")
        bounds = np.searchsorted(inverse[order], np.arange(len(values) + 1))
        for k, value in enumerate(values):
            group.add(nonzero[order[bounds[k] : bounds[k + 1]]].tolist(), float(value), "REPLACE")
    modifier = head.modifiers.new("Armature", "ARMATURE")
    modifier.object = arm_obj
    modifier.use_deform_preserve_volume = False  # FLAME is linear blend skinning


def _shape_keys(head, rig, options):
    basis = head.shape_key_add(name="Basis", from_mix=False)
    rest = rig.rest_vertices
    keys = [(f"expr_{i:03d}", rig.expr_deltas[i]) for i in rig.used_expr]
    if options.pose_correctives != "NONE":
        keys += [
            (name, d)
            for (name, _, _), d in zip(pose_corrective_names(), rig.pose_deltas, strict=True)
        ]
    for name, delta in keys:
        key = head.shape_key_add(name=name, from_mix=False)
        key.data.foreach_set("co", (rest + delta).astype(np.float32).ravel())
        key.slider_min, key.slider_max = -10.0, 10.0
    head.data.shape_keys.use_relative = True
    return basis


def _pose_drivers(head, arm_obj):
    """Corrective = (R - I) entry as a simple expression of the bone's quaternion."""
    blocks = head.data.shape_keys.key_blocks
    for name, bone, entry in pose_corrective_names():
        driver = blocks[name].driver_add("value").driver
        driver.type = "SCRIPTED"
        for channel in "wxyz":
            var = driver.variables.new()
            var.name, var.type = channel, "TRANSFORMS"
            target = var.targets[0]
            target.id, target.bone_target = arm_obj, bone
            target.transform_type = f"ROT_{channel.upper()}"
            target.rotation_mode = "QUATERNION"
            target.transform_space = "LOCAL_SPACE"
        driver.expression = POSE_FEATURE_EXPRESSIONS[entry]
        driver.use_self = False


def _animate_bones(arm_obj, rig, frames, created):
    writer = ActionWriter(arm_obj, f"{arm_obj.name}_action")
    created.add(writer.action)
    for j, name in enumerate(JOINT_NAMES):
        base = f'pose.bones["{name}"]'
        writer.write_vector(f"{base}.rotation_quaternion", frames, rig.bone_quats[:, j], name)
        writer.write_vector(f"{base}.location", frames, rig.bone_locs[:, j], name)


def _animate_shape_keys(head, rig, frames, correctives: bool, created):
    writer = ActionWriter(head.data.shape_keys, f"{head.name}_shape_keys")
    created.add(writer.action)
    for i in rig.used_expr:
        writer.write(f'key_blocks["expr_{i:03d}"].value', frames, rig.expr[:, i])
    if correctives:
        for k, (name, _, _) in enumerate(pose_corrective_names()):
            writer.write(f'key_blocks["{name}"].value', frames, rig.pose_feature[:, k])


def _build_camera(scene, seq, frames, name, created):
    height, width = (int(v) for v in seq.image_size)
    cam_data = created.add(bpy.data.cameras.new(f"{name}_camera"))
    cam = created.add(bpy.data.objects.new(f"{name}_camera", cam_data))
    scene.collection.objects.link(cam)
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.clip_start, cam_data.clip_end = 0.01, 100.0
    params = [intrinsics_to_blender(k, width, height) for k in seq.K]
    first = params[0]
    cam_data.sensor_width, cam_data.lens = first.sensor_width, first.lens
    cam_data.shift_x, cam_data.shift_y = first.shift_x, first.shift_y
    render = scene.render
    render.resolution_x, render.resolution_y = first.resolution_x, first.resolution_y
    render.resolution_percentage = 100
    render.pixel_aspect_x, render.pixel_aspect_y = first.pixel_aspect_x, first.pixel_aspect_y
    if any(p != first for p in params[1:]):  # intrinsics that change over time get keys
        data_writer = ActionWriter(cam_data, f"{name}_camera_lens")
        created.add(data_writer.action)
        for attr in ("lens", "shift_x", "shift_y"):
            data_writer.write(attr, frames, np.array([getattr(p, attr) for p in params]))
    worlds = np.stack([w2c_to_blender_matrix_world(w) for w in seq.w2c])
    cam.rotation_mode = "QUATERNION"
    # A fixed camera (most trackers': the head moves) gets no keys, so it can be moved;
    # a moving one is keyed at every tracked frame.
    if not np.allclose(worlds, worlds[:1], rtol=0.0, atol=1e-9):
        writer = ActionWriter(cam, f"{name}_camera_action")
        created.add(writer.action)
        writer.write_vector("location", frames, worlds[:, :3, 3])
        quats = np.array([Matrix(m[:3, :3].tolist()).to_quaternion()[:] for m in worlds])
        writer.write_vector("rotation_quaternion", frames, continuous_quaternions(quats))
    cam.matrix_world = Matrix(worlds[0].tolist())
    cam["archhead_head"] = name  # the N-panel shows the head while its camera is selected
    scene.camera = cam


def _store_codes(head, arm_obj, model, rig, seq, info):
    """What the decoder and the N-panel read back: identity, model, sequence facts."""
    head["archhead_identity"] = rig.identity_shape.astype(np.float32).tolist()
    if rig.identity_offset is not None:  # the avatar on this head uses it too
        head["archhead_identity_offset"] = rig.identity_offset.astype(np.float32).ravel().tolist()
    head["archhead_model_id"] = model.model_id
    head["archhead_n_expr"] = int(rig.expr.shape[1])
    for k, v in info.items():
        head[f"archhead_{k}"] = v
    # the head itself, not its name: a duplicated rig (Shift+D with its head) then names
    # the copy, as Blender remaps the pointers among the objects it duplicates
    arm_obj["archhead_head"] = head
