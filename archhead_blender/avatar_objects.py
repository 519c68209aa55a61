"""Avatar objects: which head an object belongs to, its avatar, and attaching a checkpoint to
an imported head (checks, the point object, scene setup)."""

from __future__ import annotations

from pathlib import Path

import bpy
import numpy as np

from archhead_addon.avatar.checkpoint_format import read_checkpoint
from archhead_addon.avatar.compat import HeadFacts, check_head
from archhead_addon.io.errors import InputError

from .avatar_props import is_avatar
from .avatar_session import base_model, drop_session, flame_model_path
from .handlers import refresh_avatar
from .point_instances import create_point_object, show_mean_colour
from .scene_state import head_rig

CYCLES_TRANSPARENT_BOUNCES = 256  # rays cross many overlapping Gaussians near silhouettes


def head_of(obj):
    """The imported head for an object: the head, its rig, or one of its avatars."""
    if obj is None:
        return None
    if "archhead_model_id" in obj:
        return obj
    if is_avatar(obj):
        return obj.archhead_avatar.head
    link = obj.get("archhead_head")  # the head itself; its name in files made before
    if isinstance(link, bpy.types.Object):
        return link
    return bpy.data.objects.get(link) if isinstance(link, str) and link else None


def avatar_of(head):
    """The point object showing this head's avatar, if there is one."""
    return next(
        (o for o in bpy.data.objects if is_avatar(o) and o.archhead_avatar.head == head), None
    )


def active_avatar(context):
    """The avatar point object of the active object's head."""
    head = head_of(context.active_object)
    return avatar_of(head) if head is not None else None


def selected_heads(context) -> list:
    """The heads of the active and selected objects (each once), the active one's first."""
    found = []
    for obj in [context.active_object, *getattr(context, "selected_objects", ())]:
        head = head_of(obj)
        if head is not None and head not in found:
            found.append(head)
    return found


def selected_avatars(context) -> list:
    """The avatars of the selected heads, the active one's first."""
    return [a for a in map(avatar_of, selected_heads(context)) if a is not None]


def head_facts(head) -> HeadFacts:
    mesh = head.data
    loop_uvs = None
    if mesh.uv_layers.active is not None:
        loop_uvs = np.empty(2 * len(mesh.loops), np.float32)
        mesh.uv_layers.active.data.foreach_get("uv", loop_uvs)
        loop_uvs = loop_uvs.reshape(-1, 2).astype(np.float64)
    return HeadFacts(
        model_id=str(head.get("archhead_model_id", "")),
        n_faces=len(mesh.polygons),
        identity=np.asarray(head.get("archhead_identity", []), np.float64),
        n_expr=int(head.get("archhead_n_expr", 0)),
        loop_uvs=loop_uvs,
    )


def load_avatar(context, head, path) -> tuple[bpy.types.Object, list[str]]:
    """Check the checkpoint against the head, then show it as point instances under the
    head's rig (a head's existing avatar object is reused). Returns (object, warnings)."""
    path = Path(path)
    ckpt = read_checkpoint(path)
    found = check_head(ckpt, head_facts(head), base_model(flame_model_path(context)).model_id)
    if found.errors:
        raise InputError(path, None, "; ".join(found.errors))
    obj = avatar_of(head)
    before = _data_names()
    previous = None
    if obj is not None:
        previous = (obj.archhead_avatar.checkpoint, obj.archhead_avatar.head)
    try:
        if obj is None:
            collection = (
                head.users_collection[0] if head.users_collection else context.scene.collection
            )
            obj = create_point_object(f"{head.name}_avatar", head_rig(head), collection)
        drop_session(obj)  # the same path may hold a new checkpoint (a finished training run)
        settings = obj.archhead_avatar
        settings.checkpoint = bpy.path.relpath(str(path)) if bpy.data.filepath else str(path)
        settings.head = head
        refresh_avatar(obj, context.scene, context.evaluated_depsgraph_get())
        show_mean_colour(obj)  # Solid mode's colour (Workbench draws no shader nodes)
        _make_room(head, context.scene)
    except BaseException:
        # A failed load leaves the scene as it was: what it made goes, an avatar that was
        # there keeps its checkpoint.
        if previous is not None and obj is not None:
            drop_session(obj)
            obj.archhead_avatar.checkpoint, obj.archhead_avatar.head = previous
        _remove_new_data(before)
        raise
    return obj, found.warnings


# What create_point_object may add to bpy.data (the object, its mesh, its material copy,
# the shared node group and material when the file had none yet), newest users first.
_MADE_ON_LOAD = ("objects", "meshes", "node_groups", "materials")


def _data_names() -> dict[str, set[str]]:
    return {kind: set(getattr(bpy.data, kind).keys()) for kind in _MADE_ON_LOAD}


def _remove_new_data(before: dict[str, set[str]]) -> None:
    """Remove the datablocks of the kinds above made since `before` was taken."""
    for kind in _MADE_ON_LOAD:
        blocks = getattr(bpy.data, kind)
        for name in set(blocks.keys()) - before[kind]:
            block = blocks.get(name)
            if block is not None:
                blocks.remove(block)


def _make_room(head, scene) -> None:
    """The head mesh stays evaluated (its shape keys drive the avatar) but no longer renders:
    ray visibility off (EEVEE and Cycles), only its bounds in the viewport (its wireframe
    covered the avatar), its Basis shape pinned: nothing draws the head's shape any more, so
    Blender need not add its 100-odd expression keys into it at every frame (two thirds of
    its own frame change in a crowd), while the keys' values, which drive the avatar, are
    still evaluated."""
    for flag in (
        "visible_camera",
        "visible_diffuse",
        "visible_glossy",
        "visible_transmission",
        "visible_volume_scatter",
        "visible_shadow",
    ):
        setattr(head, flag, False)
    head.display_type = "BOUNDS"
    if head.data.shape_keys is not None:
        head.active_shape_key_index = 0
        head.show_only_shape_key = True
    scene.render.use_lock_interface = True  # the handlers edit the points during renders
    cycles = getattr(scene, "cycles", None)
    if cycles is not None:
        cycles.transparent_max_bounces = max(
            cycles.transparent_max_bounces, CYCLES_TRANSPARENT_BOUNCES
        )
