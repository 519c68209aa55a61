"""What an avatar object needs at run time and cannot store in the .blend: the numpy runtime,
the decode caches and which frames were decoded. One session per point object, made on first
use from the object's settings (so a reopened .blend, a render and a farm job rebuild it).

A session lives as long as its object: Blender tells Python nothing when an object is
deleted or purged, so `prune_sessions` compares the sessions with bpy.data's objects after
every depsgraph update and frame change (the handlers) and before a new session is made.
A decoded frame set is hundreds of MB; fifteen deleted avatars held 2.5 GB before."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, replace
from pathlib import Path

import bpy
import numpy as np

from archhead_addon.avatar.checkpoint_format import read_checkpoint
from archhead_addon.avatar.culling import ViewFrustum
from archhead_addon.avatar.decode_cache import DiskCache, MemoryCache, frame_key
from archhead_addon.avatar.lod import resolution_for_lod
from archhead_addon.avatar.runtime import AvatarRuntime
from archhead_addon.avatar.scene_codes import FrameCodes, expression_joint_dirs
from archhead_addon.flame.model import FlameModel, load_model
from archhead_addon.io.digest import file_digest
from archhead_addon.splat.frame import SplatFrame

from .preferences import get_preferences
from .state import STATE, forget_object, object_uids

PRECISION = "fp32"


@dataclass
class Decoded:
    """A frame of the decode set: its cache key and what re-decodes it if evicted."""

    key: str
    codes: FrameCodes
    lod: float


def flame_model_path(context=None) -> str:
    prefs = get_preferences(context or bpy.context)
    return prefs.flame_model_path if prefs else ""


def base_model(path: str = "") -> FlameModel:
    """The FLAME model without teeth (the runtime adds them), loaded once per path."""
    key = str(path or "")
    if key not in STATE.base_models:
        STATE.base_models[key] = load_model(key or None)
    return STATE.base_models[key]


def head_identity(head) -> dict:
    """The imported head's identity as checkpoint fields: its shape code and its static
    offset (none when its tracking had none)."""
    offset = head.get("archhead_identity_offset")
    return {
        "identity_shape": np.asarray(head["archhead_identity"], np.float32),
        "identity_offset": None
        if offset is None
        else np.asarray(offset, np.float32).reshape(-1, 3),
    }


class AvatarSession:
    def __init__(self, obj):
        settings = obj.archhead_avatar
        self.source = _source(obj)
        path = Path(bpy.path.abspath(settings.checkpoint))
        ckpt = read_checkpoint(path)
        if settings.identity == "HEAD" and settings.head is not None:
            ckpt = replace(ckpt, **head_identity(settings.head))
        self.runtime = AvatarRuntime(ckpt, base_model(flame_model_path()), path)
        self.n_expr = ckpt.config.n_expr
        # The SH bands the display shows: all with view-dependent colour, else the DC term
        # alone (the others are neither decoded nor cached).
        self.sh_degree = ckpt.config.sh_degree if settings.view_dependent else 0
        self.joint_dirs = expression_joint_dirs(self.runtime.mesh, self.runtime.mesh.n_expr)
        h = hashlib.sha1(f"{file_digest(path)}/{PRECISION}/{self.sh_degree}/".encode())
        h.update(np.ascontiguousarray(ckpt.identity_shape, np.float32).tobytes())
        if ckpt.identity_offset is not None:
            h.update(np.ascontiguousarray(ckpt.identity_offset, np.float32).tobytes())
        self.digest = h.hexdigest()
        self.memory = MemoryCache(settings.memory_mb << 20)
        self.disk = _disk_cache(settings)
        self.decoded: dict[int, Decoded] = {}
        self.shown: tuple | None = None  # what the point object holds now
        self.lod_override: float | None = None  # batch renders fix the level of detail

    def key(self, codes: FrameCodes, lod: float, view=None, sh_degree=None) -> str:
        digest = codes.digest()
        if view is not None:
            digest += f"/{view.key()}"
        if sh_degree is not None and sh_degree != self.sh_degree:
            digest += f"/sh{sh_degree}"
        return frame_key(self.digest, digest, resolution_for_lod(lod)[0])

    def frame(
        self,
        codes: FrameCodes,
        lod: float,
        view: ViewFrustum | None = None,
        sh_degree: int | None = None,
    ) -> tuple[str, SplatFrame]:
        """(key, Gaussians) from memory, the disk cache or a fresh decode; `view` culls to
        a camera (a culled frame is cached under that camera); `sh_degree` overrides the
        bands the display decodes."""
        key = self.key(codes, lod, view, sh_degree)
        splat = self.memory.get(key)
        if splat is None and self.disk is not None:
            splat = self.disk.get(key)
        if splat is None:
            kwargs = codes.as_kwargs()
            kwargs["expr"] = kwargs["expr"][: self.n_expr]
            gaussians = self.runtime.decode(
                resolution_for_lod(lod)[0],
                precision=PRECISION,
                sh_degree=self.sh_degree if sh_degree is None else sh_degree,
                view=view,
                **kwargs,
            )
            splat = SplatFrame.from_gaussians(gaussians)
            if self.disk is not None:
                self.disk.put(key, splat)
        self.memory.put(key, splat)
        return key, splat


def _source(obj) -> tuple:
    """The settings a session is built from; a change of any makes a new session."""
    s = obj.archhead_avatar
    return (
        bpy.path.abspath(s.checkpoint),
        s.identity,
        s.head.name if s.head else "",
        flame_model_path(),
        s.disk_cache,
        bpy.path.abspath(s.cache_dir),
        s.memory_mb,
        s.view_dependent,
    )


def _disk_cache(settings) -> DiskCache | None:
    if not settings.disk_cache:
        return None
    folder = bpy.path.abspath(settings.cache_dir)
    if settings.cache_dir.startswith("//") and not bpy.data.filepath:
        return None  # relative to an unsaved .blend: nowhere to put it yet
    return DiskCache(folder)


def session(obj) -> AvatarSession:
    """The object's session, rebuilt when its settings changed. A failure is remembered with
    its settings and raised again without retrying (handlers ask on every update)."""
    uid, source = obj.session_uid, _source(obj)
    current = STATE.sessions.get(uid)
    if current is not None and current.source == source:
        return current
    failed = STATE.failures.get(uid)
    if failed is not None and failed[0] == source:
        raise failed[1]
    prune_sessions(force=True)
    try:
        current = STATE.sessions[uid] = AvatarSession(obj)
    except (OSError, ValueError, KeyError) as exc:  # InputError is a ValueError
        STATE.failures[uid] = (source, exc)
        raise
    STATE.failures.pop(uid, None)
    return current


def drop_session(obj) -> None:
    """Forget the object's session (its checkpoint file was replaced)."""
    STATE.sessions.pop(obj.session_uid, None)
    STATE.failures.pop(obj.session_uid, None)


def prune_sessions(force: bool = False) -> None:
    """Forget the sessions, errors and progress of objects that no longer exist. Without
    `force`, only when bpy.data's object count changed since the last check: deleting or
    purging an object changes it, and the count is cheap where reading every object's
    session_uid after every update is not (the depsgraph handler calls this)."""
    held = object_uids()
    count = len(bpy.data.objects)
    if not held or (count == STATE.objects_seen and not force):
        return
    STATE.objects_seen = count
    for uid in held - {o.session_uid for o in bpy.data.objects}:
        forget_object(uid)


def forget_shown() -> None:
    """The point objects may no longer hold what their sessions showed (undo, redo)."""
    for current in STATE.sessions.values():
        current.shown = None
