"""All of the add-on's runtime state in one place: what lives only in this Blender process and
cannot be stored in the .blend. `reset` is the one way to drop it; the handlers call it on
file load and the add-on on unregister, so no registry outlives the file it describes.
`forget_object` drops what belongs to one object: avatar_session.prune_sessions calls it for
objects that were deleted or purged, so none outlives the object it describes either.

Every other Blender-side module reads and writes these through `STATE`, never through
module-level dictionaries of its own.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass
class RuntimeState:
    # FLAME models by file path ("" = built-in): without teeth (avatar sessions), with teeth
    # (imports). Pure caches of files: kept across file loads, dropped on unregister.
    base_models: dict[str, Any] = field(default_factory=dict)
    head_models: dict[str, Any] = field(default_factory=dict)
    # Operator id -> the fields its dialog was last run with, even when it failed (Blender
    # remembers them only on success). Kept across file loads, dropped on unregister.
    dialog_fields: dict[str, dict] = field(default_factory=dict)
    # Point object session_uid -> its AvatarSession, or the settings it failed with and why.
    sessions: dict[int, Any] = field(default_factory=dict)
    failures: dict[int, tuple] = field(default_factory=dict)
    # avatar_session.decoder_key -> the SharedDecoder of every avatar with that checkpoint,
    # identity and display; dropped with its last user.
    decoders: dict[tuple, Any] = field(default_factory=dict)
    # An avatar object's name -> the session of an avatar that left the scene (undone, deleted):
    # the RETIRED most recent, kept with their decoded frames for a redo that brings the
    # object back (forget_object).
    retired: dict[str, Any] = field(default_factory=dict)
    # (path, size, mtime) -> the checkpoint file's digest: read once for a crowd of heads.
    file_digests: dict[tuple, str] = field(default_factory=dict)
    # Within one refresh of the scene (handlers.refresh_scene), path -> (size, mtime) of the
    # checkpoint files asked for; None outside it (avatar_session.file_stamp).
    file_stamps: dict[str, Any] | None = None
    # Point object session_uid -> the last error of its refresh (shown in the N-panel).
    errors: dict[int, str] = field(default_factory=dict)
    # Point object session_uid -> {"done", "total", "cancel"} of a modal decode.
    decode_progress: dict[int, dict] = field(default_factory=dict)
    # (shape-key names, n_expr) -> where the expression keys sit, pose-bone names -> where
    # the joints' bones sit (scene_state); and a head's session_uid -> {raw pose and keys:
    # FrameCodes}: the handlers' fast path.
    expression_slots: dict[tuple, Any] = field(default_factory=dict)
    joint_slots: dict[tuple, Any] = field(default_factory=dict)
    frame_codes: dict[int, dict] = field(default_factory=dict)
    # How many objects bpy.data held when the sessions were last checked against them.
    objects_seen: int = -1
    # Nesting depth of bulk work that moves frames itself (handlers pause meanwhile).
    suspended: int = 0
    # A frame was decoded since the pass before the last refresh of the scene: it asks the
    # allocator to return free pages (heap.py).
    decoded_since_release: bool = False
    # The training run the panel shows (training.TrainingRun), if one is going.
    training_run: Any = None
    # The tracking run the panel shows (tracking.TrackingRun), if one is going.
    tracking_run: Any = None
    # Avatar from Video (video_avatar.VideoAvatarRun), if one is going: its stage's tracking
    # or training run is the one above (stopped with it on quit or file load).
    video_run: Any = None


STATE = RuntimeState()


def reset(keep_models: bool = True) -> None:
    """Forget everything that belongs to the open file. A running training backend is stopped
    and waited for while it saves a checkpoint: the modal operator that watched it does not
    survive a file load, the add-on being disabled or Blender quitting (a tracking run, which
    has nothing to save, just stops). `keep_models=False` (unregister) also drops the
    model caches."""
    if STATE.training_run is not None:
        # Nothing will poll it any more (Blender quitting disables the add-ons, a file
        # load): wait while it finishes its step and saves, so the run keeps a checkpoint.
        print("ArchHead: stopping training (saving a checkpoint) ...", flush=True)
        STATE.training_run.stop_unwatched()  # says how to resume it
    if STATE.tracking_run is not None:
        STATE.tracking_run.backend.cancel()
    kept = (STATE.base_models, STATE.head_models, STATE.dialog_fields)
    kept = kept if keep_models else ({}, {}, {})
    fresh = RuntimeState(base_models=kept[0], head_models=kept[1], dialog_fields=kept[2])
    for name in RuntimeState.__dataclass_fields__:
        setattr(STATE, name, getattr(fresh, name))


def object_uids() -> set[int]:
    """The session_uids of the objects that have any per-object state."""
    return set().union(STATE.sessions, STATE.failures, STATE.errors, STATE.decode_progress)


RETIRED = 2  # sessions of avatars that left the scene, kept for a redo (forget_object)


def forget_object(uid: int) -> None:
    """Drop everything held for one object. Its session is retired rather than dropped: an
    undo past Load Avatar removes the object and a redo brings it back as a new one, which
    takes the retired session, decoded frames and all (avatar_session.session). Only the
    RETIRED most recent are kept; an older one is dropped with its share of the decoder."""
    current = STATE.sessions.get(uid)
    if current is not None:
        STATE.retired.pop(current.name, None)
        STATE.retired[current.name] = current
        while len(STATE.retired) > RETIRED:
            old = STATE.retired.pop(next(iter(STATE.retired)))
            drop_user(old.decoder_key, old.uid)
    for registry in (STATE.sessions, STATE.failures, STATE.errors, STATE.decode_progress):
        registry.pop(uid, None)
    STATE.frame_codes.pop(uid, None)  # a head's uid, when the object was a head


def drop_user(key: tuple, uid: int) -> None:
    """An object no longer uses the shared decoder of `key`; the last one frees it."""
    decoder = STATE.decoders.get(key)
    if decoder is not None and decoder.release(uid):
        del STATE.decoders[key]
