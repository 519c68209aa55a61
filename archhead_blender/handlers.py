"""Persistent handlers that keep every avatar's point instances in step with the scene.

frame_change_post (playback, scrubbing, renders, `blender -b`) and depsgraph_update_post
(an edited shape key, bone, slider or driver) both call `refresh_scene`. A change is applied
once: each avatar remembers the state it shows (the frame's cache key and, with view-dependent
colour, the camera centre) and does nothing when that state has not changed, so the handler
re-entering after its own write costs one read of the codes. Handlers never call operators.

Renders evaluate their own depsgraph and run frame_change_post on it; the point mesh changed
there is evaluated again by Blender before the frame renders. Blender requires the interface
to be locked while a handler edits data during a render (`render.use_lock_interface`), which
loading an avatar switches on.
"""

from __future__ import annotations

import bpy
from bpy.app.handlers import persistent

from archhead_addon.avatar.frame_selection import held_frame
from archhead_addon.heap import release_free_memory
from archhead_addon.io.errors import InputError
from archhead_addon.splat.frame import SplatFrame

from .avatar_props import is_avatar
from .avatar_session import (
    FrameRequest,
    forget_shown,
    prune_sessions,
    resolve_frame,
    resolve_frames,
    session,
)
from .crowd import scene_budget, scene_lods
from .lod_driver import follow_scene_camera
from .point_instances import write_points
from .scene_state import avatar_lod, camera_frustum, camera_in_object, frame_codes
from .state import STATE, reset


def suspend() -> None:
    """Bulk work that moves frames itself (decoding a frame set) pauses the refreshes."""
    STATE.suspended += 1


def resume() -> None:
    STATE.suspended = max(STATE.suspended - 1, 0)


def frame_request(
    obj,
    scene,
    depsgraph,
    culled: bool = False,
    full_colour: bool = False,
    avatar=None,
    lod: float | None = None,
) -> FrameRequest:
    """The frame the avatar shows at the scene's frame: the codes and level of detail there,
    or with "Hold" between decoded frames, the last decoded frame's; `culled` leaves out
    what the scene camera cannot see (archhead_addon.avatar.culling), `full_colour` decodes
    every SH band even where the display shows the DC term (export); `avatar`: the object's
    session when the caller has it; `lod`: the level the scene's Gaussian budget gives it
    (crowd.scene_lods), else its own."""
    avatar = avatar or session(obj)
    settings = obj.archhead_avatar
    view = camera_frustum(obj, scene, depsgraph) if culled else None
    degree = avatar.runtime.config.sh_degree if full_colour else None
    frame = scene.frame_current
    if settings.between == "HOLD" and frame not in avatar.decoded:
        held = held_frame(sorted(avatar.decoded), frame)
        if held is not None:
            record = avatar.decoded[held]
            return FrameRequest(avatar.shared, record.codes, record.lod, view, degree)
    codes = frame_codes(settings.head, depsgraph, avatar.joint_dirs)
    if lod is None:
        lod = avatar.lod_override
    if lod is None:
        lod = avatar_lod(obj, depsgraph)
    return FrameRequest(avatar.shared, codes, lod, view, degree)


def frame_to_show(obj, scene, depsgraph, culled=False, full_colour=False, lod=None):
    """(cache key, Gaussians) of `frame_request`, from the caches or decoded."""
    return resolve_frame(frame_request(obj, scene, depsgraph, culled, full_colour, lod=lod))


def culls(obj, depsgraph) -> bool:
    """Whether the avatar is culled to the scene camera in this evaluation."""
    mode = obj.archhead_avatar.cull
    return mode == "ALWAYS" or (mode == "RENDER" and depsgraph.mode == "RENDER")


def refresh_avatar(obj, scene, depsgraph, lod: float | None = None) -> bool:
    """Bring one avatar's points up to date (at `lod` when the scene's budget sets it); True
    if they were rewritten."""
    avatar = session(obj)
    request = frame_request(obj, scene, depsgraph, culls(obj, depsgraph), avatar=avatar, lod=lod)
    return _show(obj, avatar, resolve_frame(request), scene, depsgraph)


def _show(obj, avatar, found: tuple[str, SplatFrame], scene, depsgraph) -> bool:
    """Write a resolved frame into the avatar's points, unless they show it already."""
    key, splat = found
    view_from = None
    if avatar.sh_degree > 0:  # view-dependent colour on an avatar that has it
        view_from = camera_in_object(obj, scene, depsgraph)
    state = (key, None if view_from is None else tuple(view_from.round(6)))
    if state == avatar.shown:
        return False
    write_points(obj, avatar.shared.points(key, splat, view_from))
    avatar.shown = state
    return True


def refresh_scene(scene, depsgraph) -> None:
    prune_sessions()  # an avatar deleted or purged since the last update frees its memory
    if STATE.suspended:
        return
    # Free pages go back to the system after a pass that decoded (its temporaries) and once
    # more at the next pass (what Blender freed evaluating the points written).
    if STATE.decoded_since_release:
        STATE.decoded_since_release = False
        release_free_memory()
    STATE.file_stamps = {}  # each checkpoint file is asked for its time once in this pass
    try:
        _refresh_avatars(scene, depsgraph)
    finally:
        STATE.file_stamps = None
    if STATE.decoded_since_release:
        release_free_memory()


_AVATAR_ERRORS = (InputError, OSError, ValueError, KeyError)  # an avatar's, said in the console


def _refresh_avatars(scene, depsgraph) -> None:
    """Every avatar's frame found first, the missing ones decoded together
    (`resolve_frames`), then each avatar's points written."""
    lods = None
    if scene_budget(scene):
        try:
            lods = scene_lods(scene, depsgraph)
        except _AVATAR_ERRORS as exc:
            print(f"ArchHead: the scene's Gaussian budget is not applied: {exc}")
    pending = []
    for obj in scene.objects:
        if not is_avatar(obj):
            continue
        try:
            follow_scene_camera(obj, scene)  # takes effect at the next evaluation
            lod = None if lods is None else lods.get(obj.session_uid)
            avatar = session(obj)
            culled = culls(obj, depsgraph)
            request = frame_request(obj, scene, depsgraph, culled, avatar=avatar, lod=lod)
            pending.append((obj, avatar, request))
        except _AVATAR_ERRORS as exc:
            _report(obj, exc)
    found = resolve_frames([request for _, _, request in pending])
    for (obj, avatar, _), frame in zip(pending, found, strict=True):
        try:
            if isinstance(frame, Exception):
                raise frame
            _show(obj, avatar, frame, scene, depsgraph)
            STATE.errors.pop(obj.session_uid, None)
        except _AVATAR_ERRORS as exc:
            _report(obj, exc)


def _report(obj, exc: Exception) -> None:
    if STATE.errors.get(obj.session_uid) != str(exc):  # say it once, not every update
        print(f"ArchHead: {obj.name}: {exc}")
    STATE.errors[obj.session_uid] = str(exc)


@persistent
def on_frame_change(scene, depsgraph):
    refresh_scene(scene, depsgraph)


@persistent
def on_depsgraph_update(scene, depsgraph):
    refresh_scene(scene, depsgraph)


@persistent
def on_load(_filepath):
    """A new file: its objects have new session ids, and a decode or training run that the
    old file's modal operator watched is gone with it (a paused decode never resumed)."""
    reset()


@persistent
def on_undo(*_args):
    """Undo and redo put back older point data: show the scene's state again."""
    forget_shown()


_HANDLERS = (
    (bpy.app.handlers.frame_change_post, on_frame_change),
    (bpy.app.handlers.depsgraph_update_post, on_depsgraph_update),
    (bpy.app.handlers.load_post, on_load),
    (bpy.app.handlers.undo_post, on_undo),
    (bpy.app.handlers.redo_post, on_undo),
)


def register():
    for handlers, fn in _HANDLERS:
        if fn not in handlers:
            handlers.append(fn)


def unregister():
    for handlers, fn in _HANDLERS:
        while fn in handlers:
            handlers.remove(fn)
