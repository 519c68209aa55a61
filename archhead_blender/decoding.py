"""Decode an avatar's frame set (keyed frames, every frame or a stride, in the scene's range)
into the caches, each frame at the level of detail it will have.

The Decode operator (operators/avatar_decode.py) runs `decode_frame` one frame per timer tick;
scripts call `decode_frames`, which does the same work in one go.
"""

from __future__ import annotations

from archhead_addon.avatar.frame_selection import frames_to_decode

from .avatar_session import Decoded, session
from .handlers import refresh_avatar, resume, suspend
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


def decode_frame(context, obj, frame: int) -> None:
    """Move to `frame`, read the codes and level of detail there, decode into the caches."""
    avatar = session(obj)
    context.scene.frame_set(frame)
    depsgraph = context.evaluated_depsgraph_get()
    codes = frame_codes(obj.archhead_avatar.head, depsgraph, avatar.joint_dirs)
    lod = avatar.lod_override if avatar.lod_override is not None else avatar_lod(obj, depsgraph)
    key, _ = avatar.frame(codes, lod)
    avatar.decoded[frame] = Decoded(key, codes, lod)


def decode_frames(context, obj, frames=None) -> int:
    """Decode `frames` (default: the object's decode set); returns how many."""
    scene = context.scene
    frames = decode_set(scene, obj) if frames is None else list(frames)
    session(obj).decoded.clear()
    start = scene.frame_current
    suspend()
    try:
        for frame in frames:
            decode_frame(context, obj, frame)
    finally:
        scene.frame_set(start)
        resume()
    refresh_avatar(obj, scene, context.evaluated_depsgraph_get())
    return len(frames)
