"""Decode an avatar's frame set (keyed frames, every frame or a stride, in the scene's range)
into the caches, each frame at the level of detail it will have.

The Decode operator (operators/avatar_decode.py) runs `decode_frame` one frame per timer tick;
scripts, batch renders and `--decode-only` call `decode_frames`, which does the same work in
one go. Both take several avatars and visit each frame once for all of them.
"""

from __future__ import annotations

from archhead_addon.avatar.frame_selection import frames_to_decode

from .avatar_session import Decoded, FrameRequest, resolve_frames, session
from .crowd import scene_lods
from .handlers import refresh_scene, resume, suspend
from .scene_state import avatar_lod, frame_codes, head_rig, keyed_frames


def decode_set(scene, obj) -> list[int]:
    settings = obj.archhead_avatar
    head = settings.head
    keyed = ()
    if settings.decode_frames == "KEYED":
        keyed = keyed_frames(head_rig(head), head.data.shape_keys, obj)
    return frames_to_decode(
        settings.decode_frames, scene.frame_start, scene.frame_end, keyed, settings.stride
    )


def decode_frame(context, objs, frame: int) -> None:
    """Move to `frame` once and decode every avatar of `objs` there (the codes and level of
    detail of each) into the caches. One scene evaluation serves them all: stepping the scene
    per avatar made a crowd's decode grow as the square of its heads."""
    avatars = [(obj, session(obj)) for obj in objs]
    context.scene.frame_set(frame)
    depsgraph = context.evaluated_depsgraph_get()
    budgeted = scene_lods(context.scene, depsgraph) or {}  # the whole scene's, when it has one
    requests = []
    for obj, avatar in avatars:
        codes = frame_codes(obj.archhead_avatar.head, depsgraph, avatar.joint_dirs)
        lod = budgeted.get(obj.session_uid, avatar.lod_override)
        if lod is None:
            lod = avatar_lod(obj, depsgraph)
        requests.append(FrameRequest(avatar.shared, codes, lod))
    found_all = resolve_frames(requests)  # decoded together: a crowd's heads on every core
    for (_, avatar), request, found in zip(avatars, requests, found_all, strict=True):
        if isinstance(found, Exception):
            raise found
        avatar.decoded[frame] = Decoded(found[0], request.codes, request.lod)


def scene_plan(scene, objs, frames=None) -> list[tuple[int, list]]:
    """(frame, the avatars that decode it) in frame order: each avatar's own decode set, or
    `frames` for all of them."""
    wanted: dict[int, list] = {}
    for obj in objs:
        for frame in decode_set(scene, obj) if frames is None else frames:
            wanted.setdefault(int(frame), []).append(obj)
    return sorted(wanted.items())


def decode_frames(context, objs, frames=None) -> int:
    """Decode `frames` (default: each avatar's decode set) of one avatar or several in one
    pass over the scene's frames; returns how many frames were visited."""
    objs = [objs] if not isinstance(objs, list | tuple) else list(objs)
    scene = context.scene
    plan = scene_plan(scene, objs, frames)
    for obj in objs:
        session(obj).decoded.clear()
    start = scene.frame_current
    suspend()
    try:
        for frame, members in plan:
            decode_frame(context, members, frame)
    finally:
        scene.frame_set(start)
        resume()
    refresh_scene(scene, context.evaluated_depsgraph_get())
    return len(plan)
