"""What an avatar object needs at run time and cannot store in the .blend: the numpy runtime,
the decode caches and which frames were decoded. One session per point object, made on first
use from the object's settings (so a reopened .blend, a render and a farm job rebuild it).

A session lives as long as its object: Blender tells Python nothing when an object is
deleted or purged, so `prune_sessions` compares the sessions with bpy.data's objects after
every depsgraph update and frame change (the handlers) and before a new session is made.
A decoded frame set is hundreds of MB: unpruned, fifteen deleted avatars hold 2.5 GB."""

from __future__ import annotations

import functools
import hashlib
from dataclasses import dataclass, replace
from pathlib import Path

import bpy
import numpy as np

from archhead_addon.avatar.checkpoint_format import read_checkpoint
from archhead_addon.avatar.culling import REACH_PAD, SIGMAS, ViewFrustum
from archhead_addon.avatar.decode_cache import DiskCache, MemoryCache, frame_key
from archhead_addon.avatar.lod import resolution_for_lod
from archhead_addon.avatar.point_attributes import point_attributes
from archhead_addon.avatar.runtime import LEVEL_BYTES, AvatarRuntime, decode_batch
from archhead_addon.avatar.scene_codes import FrameCodes, expression_joint_dirs
from archhead_addon.flame.model import FlameModel, load_model
from archhead_addon.io.digest import file_digest
from archhead_addon.splat.frame import SplatFrame

from .preferences import get_preferences, memory_total_bytes
from .state import STATE, drop_user, forget_object, object_uids

PRECISION = "fp32"
# Per-resolution tables of a shared runtime: room for one per head, each at its own resolution
# (a full-size avatar's S = 256 takes 49 MB), up to every resolution's (2.5 GB full size).
LEVEL_BYTES_PER_HEAD, LEVEL_BYTES_MAX = 48 << 20, 3 << 30


@dataclass
class CachedFrame:
    """A memory cache entry: the frame, and its point attributes without a camera (what its
    display writes), made once when it enters the cache, so that a cached frame shown again
    costs only its write. Its bytes count both (position and rotation are the frame's own
    arrays)."""

    splat: SplatFrame
    points: dict

    @property
    def nbytes(self) -> int:
        own = (self.splat.means, self.splat.quats)
        extra = sum(a.nbytes for a in self.points.values() if not any(a is b for b in own))
        return self.splat.nbytes + extra


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


class SharedDecoder:
    """What every avatar of one checkpoint, identity and display shares: the numpy runtime
    (its weights and level tables, about 100 MB), the memory cache and the disk cache. A
    crowd of heads that use one checkpoint decodes through one of these; per avatar remain
    only its codes, level of detail and object (AvatarSession)."""

    def __init__(self, key: tuple, settings):
        """`key`: its `decoder_key` (the checkpoint's path and digest first)."""
        path = Path(key[0])
        ckpt = read_checkpoint(path)
        if settings.identity == "HEAD" and settings.head is not None:
            ckpt = replace(ckpt, **head_identity(settings.head))
        self.runtime = AvatarRuntime(ckpt, base_model(flame_model_path()), path)
        self.n_expr = ckpt.config.n_expr
        # The SH bands the display shows: all with view-dependent colour, else the DC term
        # alone (the others are neither decoded nor cached).
        self.sh_degree = ckpt.config.sh_degree if settings.view_dependent else 0
        self.joint_dirs = expression_joint_dirs(self.runtime.mesh, self.runtime.mesh.n_expr)
        self.digest = key[1]
        self.memory = MemoryCache(0)
        self.disk = _disk_cache(settings)
        self.budgets: dict[int, int] = {}  # user's session_uid -> its memory budget, bytes
        self.texel_counts: dict[int, int] = {}  # UV resolution -> texels (the scene budget)

    def texels(self, size: int) -> int:
        """The avatar's texels at UV resolution `size` (its Gaussians before opacity and
        culling), counted once per size."""
        count = self.texel_counts.get(size)
        if count is None:
            count = self.texel_counts[size] = len(self.runtime.raster.table(size).texel)
        return count

    def texels_at_ends(self) -> tuple[int, int]:
        """texels() at LOD 0 and at LOD 1."""
        cfg = self.runtime.config
        return self.texels(cfg.s_max), self.texels(cfg.s_min)

    def use(self, uid: int, memory_mb: int) -> None:
        """Count an avatar among the users: the memory cache holds the sum of their budgets
        (each head's frames are its own; a shared budget would evict a crowd's every frame)
        within the share of all avatars' memory (balance_memory), and the per-resolution
        tables grow with the heads, each at its own resolution (a table rebuilt costs about a
        decode)."""
        self.budgets[uid] = memory_mb << 20
        self._resize()

    @property
    def wanted_bytes(self) -> int:
        return sum(self.budgets.values())

    def _resize(self) -> None:
        balance_memory()
        users = len(self.budgets)
        self.runtime.level.max_bytes = min(
            max(LEVEL_BYTES, users * LEVEL_BYTES_PER_HEAD), LEVEL_BYTES_MAX
        )

    def release(self, uid: int) -> bool:
        """Forget a user; True when none is left (the decoder can go)."""
        self.budgets.pop(uid, None)
        self._resize()
        return not self.budgets

    def key(self, codes: FrameCodes, lod: float, view=None, sh_degree=None) -> str:
        digest = codes.digest()
        if view is not None:
            digest += f"/{view.key()}"
        if sh_degree is not None and sh_degree != self.sh_degree:
            digest += f"/sh{sh_degree}"
        return frame_key(self.digest, digest, resolution_for_lod(lod)[0])

    def cached(self, key: str) -> SplatFrame | None:
        entry = self._entry(key)
        return None if entry is None else entry.splat

    def _entry(self, key: str) -> CachedFrame | None:
        entry = self.memory.get(key)
        if entry is None and self.disk is not None:
            splat = self.disk.get(key)
            if splat is not None:
                entry = self._keep(key, splat)
        return entry

    def _keep(self, key: str, splat: SplatFrame) -> CachedFrame:
        entry = CachedFrame(splat, point_attributes(splat, None, self.colour_space))
        self.memory.put(key, entry)
        return entry

    @property
    def colour_space(self) -> str:
        return self.runtime.config.colour_space

    def points(self, key: str, splat: SplatFrame, view_from=None) -> dict:
        """`point_attributes` of a frame that `frame` returned under `key`: a cached whole
        frame's without a camera come from its cache entry."""
        if view_from is None:
            entry = self.memory.get(key)
            if entry is not None and entry.splat is splat:
                return entry.points
        return point_attributes(splat, view_from, self.colour_space)

    def frame(
        self,
        codes: FrameCodes,
        lod: float,
        view: ViewFrustum | None = None,
        sh_degree: int | None = None,
    ) -> tuple[str, SplatFrame]:
        """(key, Gaussians) from memory, the disk cache or a fresh decode."""
        return resolve_frame(FrameRequest(self, codes, lod, view, sh_degree))

    def lookup(self, request: FrameRequest) -> tuple[str, SplatFrame | None]:
        """(key, Gaussians) of a request from memory or the disk cache, None where it needs
        a decode. A culled request is cut from the whole frame when a cache holds it (cheap,
        so frames decoded ahead serve every camera), else decoded culled and cached under
        its camera."""
        codes, lod, view, degree = request.codes, request.lod, request.view, request.sh_degree
        key = self.key(codes, lod, view, degree)
        splat = self.cached(key)
        if splat is None and view is not None:
            whole = self.cached(self.key(codes, lod, None, degree))
            if whole is not None:
                return key, cull_frame(whole, view)
        return key, splat

    def decode(self, request: FrameRequest, posed=None) -> CachedFrame:
        """A fresh decode of a request, as its cache entry: numpy alone, so that
        `resolve_frames` runs several on threads of their own (nothing here touches bpy or
        the caches). `posed`: its head from `runtime.pose`, posed with others'."""
        gaussians = self.runtime.decode(
            resolution_for_lod(request.lod)[0],
            precision=PRECISION,
            sh_degree=self.sh_degree if request.sh_degree is None else request.sh_degree,
            view=request.view,
            posed=posed,
            **self.codes(request),
        )
        splat = SplatFrame.from_gaussians(gaussians)
        return CachedFrame(splat, point_attributes(splat, None, self.colour_space))

    def codes(self, request: FrameRequest) -> dict:
        """The request's codes as `runtime.decode` and `runtime.pose` take them."""
        kwargs = request.codes.as_kwargs()
        kwargs["expr"] = kwargs["expr"][: self.n_expr]
        return kwargs

    def store(self, key: str, entry: CachedFrame) -> SplatFrame:
        """Keep a decoded frame in the memory cache (and the disk cache)."""
        STATE.decoded_since_release = True
        if self.disk is not None:
            self.disk.put(key, entry.splat)
        self.memory.put(key, entry)
        return entry.splat


@dataclass(frozen=True)
class FrameRequest:
    """A frame an avatar is to show: its codes and level of detail, the camera it is culled
    to (or None) and the SH bands, when not the display's."""

    decoder: SharedDecoder
    codes: FrameCodes
    lod: float
    view: ViewFrustum | None = None
    sh_degree: int | None = None

    def texels(self) -> int:
        return self.decoder.texels(self.decoder.runtime.resolution(self.lod))


def resolve_frame(request: FrameRequest) -> tuple[str, SplatFrame]:
    """`resolve_frames` of one request; a failed decode raises."""
    found = resolve_frames([request])[0]
    if isinstance(found, Exception):
        raise found
    return found


def resolve_frames(requests: list[FrameRequest]) -> list:
    """Each request's (key, Gaussians): from the caches, else decoded, together
    (`decode_requests`), each frame once however many requests ask for it. A decode that
    fails leaves its exception in its requests' places."""
    results: list = [None] * len(requests)
    wanted: dict[tuple, tuple[str, FrameRequest, list[int]]] = {}
    for i, request in enumerate(requests):
        key, splat = request.decoder.lookup(request)
        if splat is not None:
            results[i] = (key, splat)
        else:
            wanted.setdefault((id(request.decoder), key), (key, request, []))[2].append(i)
    if not wanted:
        return results
    jobs = list(wanted.values())
    entries = decode_requests([request for _, request, _ in jobs])
    for (key, request, places), entry in zip(jobs, entries, strict=True):
        found = entry if isinstance(entry, Exception) else (key, request.decoder.store(key, entry))
        for i in places:
            results[i] = found
    return results


def decode_requests(requests: list[FrameRequest]) -> list:
    """Fresh decodes of `requests` (cache entries, or the exception a decode raised), run
    together: the heads of one decoder posed in one pass (`_posed`), then their decodes on
    every core at once (`decode_batch`: a crowd's heads, benchmarks/crowd.py)."""
    posed = _posed(requests)
    return decode_batch(
        [
            functools.partial(request.decoder.decode, request, head)
            for request, head in zip(requests, posed, strict=True)
        ],
        [request.texels() for request in requests],
    )


def _posed(requests: list[FrameRequest]) -> list:
    """Each request's posed head, the heads of one decoder posed in one batched pass
    (`AvatarRuntime.pose`); None where a decoder has one request or posing failed (its
    decode poses it and says what was wrong)."""
    groups: dict[int, list[int]] = {}
    for i, request in enumerate(requests):
        groups.setdefault(id(request.decoder), []).append(i)
    posed: list = [None] * len(requests)
    for places in groups.values():
        if len(places) < 2:
            continue
        decoder = requests[places[0]].decoder
        try:
            heads = decoder.runtime.pose([decoder.codes(requests[i]) for i in places])
        except ValueError:
            continue
        for i, head in zip(places, heads, strict=True):
            posed[i] = head
    return posed


class AvatarSession:
    """One avatar object's state beside its shared decoder: the frames it decoded, what its
    point mesh shows and a batch render's fixed level of detail."""

    def __init__(self, obj):
        self.name, self.uid = obj.name, obj.session_uid
        self.source = _source(obj)
        self.decoder_key = decoder_key(obj)
        self.shared = shared_decoder(self.decoder_key, obj)
        self.decoded: dict[int, Decoded] = {}
        self.shown: tuple | None = None  # what the point object holds now
        self.lod_override: float | None = None  # batch renders fix the level of detail

    @property
    def runtime(self) -> AvatarRuntime:
        return self.shared.runtime

    @property
    def sh_degree(self) -> int:
        return self.shared.sh_degree

    @property
    def joint_dirs(self):
        return self.shared.joint_dirs

    def frame(self, codes, lod, view=None, sh_degree=None) -> tuple[str, SplatFrame]:
        return self.shared.frame(codes, lod, view, sh_degree)


def balance_memory() -> None:
    """Each shared decoder's memory cache: its users' budgets, scaled down together where
    all of them would pass the preferences' total for all avatars."""
    decoders = list(STATE.decoders.values())
    wanted = sum(d.wanted_bytes for d in decoders)
    scale = min(1.0, memory_total_bytes() / wanted) if wanted else 1.0
    for d in decoders:
        d.memory.resize(int(d.wanted_bytes * scale))


def shared_decoder(key: tuple, obj) -> SharedDecoder:
    """The decoder of `key` (`decoder_key`), made on first use, with `obj` among its users."""
    settings = obj.archhead_avatar
    current = STATE.decoders.get(key)
    if current is None:
        current = STATE.decoders[key] = SharedDecoder(key, settings)
    current.use(obj.session_uid, settings.memory_mb)
    return current


def cull_frame(splat: SplatFrame, view: ViewFrustum) -> SplatFrame:
    """The Gaussians of a decoded frame that `view` can see (a sphere of SIGMAS standard
    deviations around each mean meets the frustum): the culling of a cached whole frame."""
    extent = SIGMAS * np.exp(splat.log_scales.max(axis=1)) + REACH_PAD
    keep = view.visible(splat.means.T, extent)
    kept = {k: v[keep] for k, v in splat.arrays().items()}
    return SplatFrame(**kept, resolution=splat.resolution)


def _source(obj) -> tuple:
    """The settings a session is built from, and the checkpoint file's size and time: a
    change of any makes a new session. Cheap, as the handlers ask for it after every update
    of every avatar (the file's digest and the identity are read only when it changes)."""
    s = obj.archhead_avatar
    path = bpy.path.abspath(s.checkpoint)
    head = s.head.session_uid if s.head is not None else None
    return (path, file_stamp(path), s.identity, head, flame_model_path(), s.disk_cache,
            bpy.path.abspath(s.cache_dir), s.view_dependent, s.memory_mb)  # fmt: skip


def file_stamp(path: str) -> tuple | None:
    """(size, modification time) of a file, or None where it cannot be read. Within one
    refresh of the scene (`STATE.file_stamps` set) each file is asked once: a crowd of heads
    shares one checkpoint."""
    memo = STATE.file_stamps
    if memo is not None and path in memo:
        return memo[path]
    try:
        stat = Path(path).stat()
        stamp = (stat.st_size, stat.st_mtime_ns)
    except OSError:
        stamp = None
    if memo is not None:
        memo[path] = stamp
    return stamp


def decoder_key(obj) -> tuple:
    """What avatars must agree on to share a decoder: the checkpoint (its path, and the
    digest of its file and of the identity it is drawn with), the FLAME model and the
    display and disk cache settings."""
    s = obj.archhead_avatar
    path = bpy.path.abspath(s.checkpoint)
    return (path, _identity_digest(path, s), flame_model_path(), s.disk_cache,
            bpy.path.abspath(s.cache_dir), s.view_dependent)  # fmt: skip


def _identity_digest(path: str, settings) -> str:
    """The digest of the checkpoint file and the identity the avatar is drawn with (the
    head's when it follows the head): the cache keys' prefix. The file's digest is kept by
    its size and modification time (a crowd of heads reads the file once)."""
    try:
        stat = Path(path).stat()
        stamp = (path, stat.st_size, stat.st_mtime_ns)
        digest = STATE.file_digests.get(stamp)
        if digest is None:
            digest = STATE.file_digests[stamp] = file_digest(path)
        h = hashlib.sha1(f"{digest}/{PRECISION}/{settings.view_dependent}/".encode())
        if settings.identity == "HEAD" and settings.head is not None:
            identity = head_identity(settings.head)
            h.update(np.ascontiguousarray(identity["identity_shape"], np.float32).tobytes())
            if identity["identity_offset"] is not None:
                h.update(np.ascontiguousarray(identity["identity_offset"], np.float32).tobytes())
    except (OSError, KeyError, ValueError, TypeError):
        return "unreadable"  # the session's own reading of the file says what is wrong
    return h.hexdigest()


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
    if current is not None:  # its settings changed: it leaves its old decoder
        drop_user(current.decoder_key, uid)
        del STATE.sessions[uid]
    returned = _returning(obj, source)
    if returned is not None:
        STATE.sessions[uid] = returned
        return returned
    try:
        current = STATE.sessions[uid] = AvatarSession(obj)
    except (OSError, ValueError, KeyError) as exc:  # InputError is a ValueError
        STATE.failures[uid] = (source, exc)
        raise
    STATE.failures.pop(uid, None)
    return current


def _returning(obj, source: tuple) -> AvatarSession | None:
    """The retired session of an avatar object that came back (a redo of Load Avatar, an
    undone delete: a new object of the old one's name and settings), taken over by it."""
    retired = STATE.retired.get(obj.name)
    if retired is None or retired.source != source:
        return None
    del STATE.retired[obj.name]
    retired.shared.use(obj.session_uid, obj.archhead_avatar.memory_mb)
    if retired.uid != obj.session_uid:
        retired.shared.release(retired.uid)
    retired.uid, retired.shown = obj.session_uid, None
    return retired


def drop_session(obj) -> None:
    """Forget the object's session (its checkpoint file was replaced)."""
    current = STATE.sessions.pop(obj.session_uid, None)
    if current is not None:
        drop_user(current.decoder_key, obj.session_uid)
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
