"""Read what the scene says about an avatar at the current frame: the FLAME codes the head
carries (expression shape keys, bone rotations, root location), its level of detail, the
camera. Values come from the evaluated depsgraph, so keyframes, drivers and NLA all count,
in the viewport and in renders (whose depsgraph never writes back to the original data).
"""

from __future__ import annotations

import numpy as np

from archhead_addon.avatar.culling import ViewFrustum
from archhead_addon.avatar.scene_codes import FrameCodes, codes_from_rig
from archhead_addon.camera import BlenderCamera, affine_inverse
from archhead_addon.flame.model import JOINT_NAMES
from archhead_addon.splat.blender_render import blender_camera_to_opencv

from .state import STATE


def head_rig(head):
    """The armature that carries the head's bones (its parent, as the import builds it)."""
    rig = head.parent
    if rig is None or rig.type != "ARMATURE":
        raise ValueError(f"'{head.name}' is not an imported ArchHead head (no rig parent)")
    return rig


def expression_values(head, depsgraph, n_expr: int) -> np.ndarray:
    """The values of expr_000 .. expr_{n-1} (a muted or missing key counts as 0)."""
    key = head.data.shape_keys
    if key is None or n_expr == 0:
        return np.zeros(n_expr)
    blocks = key.evaluated_get(depsgraph).key_blocks
    names = tuple(blocks.keys())  # its length too: len() walks Blender's list again
    values = np.zeros(len(names) + 1, np.float32)  # the last: what a missing key reads
    blocks.foreach_get("value", values[:-1])
    muted = np.empty(len(names), bool)
    blocks.foreach_get("mute", muted)
    values[:-1][muted] = 0.0
    return values[_expression_slots(names, n_expr)].astype(np.float64)


def _expression_slots(names: tuple, n_expr: int) -> np.ndarray:
    """Where expr_000 .. expr_{n-1} sit among the shape keys `names` (len(names) for a
    missing one), kept per name list: the handlers ask for every head after every update."""
    slots = STATE.expression_slots.get((names, n_expr))
    if slots is None:
        index = {name: j for j, name in enumerate(names)}
        slots = np.array([index.get(f"expr_{i:03d}", len(names)) for i in range(n_expr)])
        if len(STATE.expression_slots) > 64:  # heads of other models and key sets come and go
            STATE.expression_slots.clear()
        STATE.expression_slots[names, n_expr] = slots
    return slots


# Raw pose and keys -> codes remembered per head: a frame shown again (playback of decoded
# frames, a render after Decode Frames) skips the conversion to axis-angles, which costs more
# than the rest of showing a cached frame. An entry is about 2 KB: at most 2 MB a head.
CODES_MEMO = 1024


def frame_codes(head, depsgraph, joint_dirs: np.ndarray) -> FrameCodes:
    rig = head_rig(head).evaluated_get(depsgraph)
    basis = joint_basis(rig)
    n_expr = min(int(head.get("archhead_n_expr", 0)), len(joint_dirs))
    expr = expression_values(head, depsgraph, n_expr)
    raw = (basis.tobytes(), expr.tobytes(), id(joint_dirs))
    memo = STATE.frame_codes.setdefault(head.session_uid, {})
    codes = memo.get(raw)
    if codes is None:
        rotations = basis[:, :3, :3] / np.linalg.norm(basis[:, :3, :3], axis=1, keepdims=True)
        codes = codes_from_rig(rotations, basis[0, :3, 3], expr, joint_dirs)
        if len(memo) >= CODES_MEMO:
            memo.clear()
        memo[raw] = codes
    return codes


def joint_basis(rig) -> np.ndarray:
    """(5,4,4) float32: the local matrices (matrix_basis) of the FLAME joints' bones, in
    JOINT_NAMES order, read in one bulk call. KeyError names a missing bone."""
    bones = rig.pose.bones
    names = tuple(bones.keys())
    flat = np.empty(len(names) * 16, np.float32)
    bones.foreach_get("matrix_basis", flat)  # column-major, as Blender stores matrices
    return flat.reshape(-1, 4, 4).transpose(0, 2, 1)[_joint_slots(names)]


def _joint_slots(names: tuple) -> np.ndarray:
    """Where JOINT_NAMES sit among a rig's pose bones `names`, kept per name list."""
    slots = STATE.joint_slots.get(names)
    if slots is None:
        index = {name: j for j, name in enumerate(names)}
        missing = [name for name in JOINT_NAMES if name not in index]
        if missing:
            raise KeyError(f"the rig has no bone '{missing[0]}'")
        if len(STATE.joint_slots) > 64:
            STATE.joint_slots.clear()
        slots = STATE.joint_slots[names] = np.array([index[name] for name in JOINT_NAMES])
    return slots


def avatar_lod(obj, depsgraph) -> float:
    return float(obj.evaluated_get(depsgraph).archhead_avatar.lod)


def camera_in_object(obj, scene, depsgraph):
    """The scene camera's centre in the object's own space (FLAME space), or None."""
    if scene.camera is None:
        return None
    camera = np.array(scene.camera.evaluated_get(depsgraph).matrix_world)
    world = np.array(obj.evaluated_get(depsgraph).matrix_world)
    return (affine_inverse(world) @ camera[:, 3])[:3]


def blender_camera(scene) -> BlenderCamera:
    """The scene camera's projection settings at the current frame."""
    if scene.camera is None or scene.camera.type != "CAMERA" or scene.camera.data.type != "PERSP":
        raise ValueError("exact splat renders need a perspective scene camera")
    data, r = scene.camera.data, scene.render
    scale = r.resolution_percentage / 100.0
    return BlenderCamera(
        lens=data.lens,
        sensor_width=data.sensor_width,
        shift_x=data.shift_x,
        shift_y=data.shift_y,
        resolution_x=round(r.resolution_x * scale),
        resolution_y=round(r.resolution_y * scale),
        pixel_aspect_x=r.pixel_aspect_x,
        pixel_aspect_y=r.pixel_aspect_y,
        sensor_fit=data.sensor_fit,
        sensor_height=data.sensor_height,
    )


def camera_frustum(obj, scene, depsgraph) -> ViewFrustum | None:
    """The scene camera's view volume in the object's own space (FLAME space), or None where
    there is no perspective camera to cull to."""
    camera = scene.camera
    if camera is None or camera.type != "CAMERA" or camera.data.type != "PERSP":
        return None
    settings = blender_camera(scene)
    viewmat, K = blender_camera_to_opencv(
        settings,
        np.array(camera.evaluated_get(depsgraph).matrix_world),
        np.array(obj.evaluated_get(depsgraph).matrix_world),
    )
    near = camera.data.clip_start
    return ViewFrustum.from_camera(viewmat, K, settings.resolution_x, settings.resolution_y, near)


def _fcurves(id_data):
    anim = id_data.animation_data if id_data is not None else None
    if anim is None or anim.action is None:
        return []
    action = anim.action
    if not getattr(action, "layers", None):  # a classic action (before Blender 4.4)
        return list(action.fcurves)
    out = []
    for layer in action.layers:
        for strip in layer.strips:
            bag = strip.channelbag(anim.action_slot) if anim.action_slot else None
            out.extend(bag.fcurves if bag else [])
    return out


def keyed_frames(*ids) -> set[float]:
    """Frames that carry a key on any F-curve of these IDs (rig, shape keys, avatar)."""
    frames: set[float] = set()
    for fc in (fc for id_data in ids for fc in _fcurves(id_data)):
        co = np.empty(2 * len(fc.keyframe_points), np.float32)
        fc.keyframe_points.foreach_get("co", co)
        frames.update(co[0::2].tolist())
    return frames
