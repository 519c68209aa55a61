"""Decoded frames kept for playback: in memory (least recently used out, by bytes) and,
optionally, on disk as one npz per frame (written atomically, so render-farm machines can
share a cache folder and a crash never leaves a torn file) with a checksum of its arrays: a
file that fails it, or any other check, is deleted and its frame decoded again.

A frame is named by `frame_key`: the avatar (checkpoint contents, identity, precision), the
codes and the level of detail, never the frame number, so an edit to any code makes a new
key and two frames with the same codes share one entry.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from pathlib import Path

import numpy as np

from ..io.atomic import remove_stale_temporaries, save_npz_atomic
from ..io.checksum import KEY, verify, with_checksum
from ..io.errors import InputError
from ..io.npz import read_npz
from ..io.schema import check_finite
from ..splat.frame import SplatFrame
from .config import SIZE_LIMITS


def frame_key(avatar_digest: str, codes_digest: str, lod: float) -> str:
    """The cache name of one decoded frame."""
    h = hashlib.sha1(f"{avatar_digest}/{codes_digest}".encode())
    h.update(np.float64(lod).tobytes())
    return h.hexdigest()[:24]


class MemoryCache:
    """Least recently used frames out once their bytes pass the budget. A value is a
    SplatFrame or anything else with `nbytes` (a frame with what its display derives)."""

    def __init__(self, max_bytes: int):
        self.max_bytes = int(max_bytes)
        self._frames: OrderedDict = OrderedDict()
        self.nbytes = 0

    def get(self, key: str):
        frame = self._frames.get(key)
        if frame is not None:
            self._frames.move_to_end(key)
        return frame

    def put(self, key: str, frame) -> None:
        if key in self._frames:
            self.nbytes -= self._frames.pop(key).nbytes
        self._frames[key] = frame
        self.nbytes += frame.nbytes
        self._evict()

    def resize(self, max_bytes: int) -> None:
        """A new budget; a smaller one evicts at once."""
        self.max_bytes = int(max_bytes)
        self._evict()

    def _evict(self) -> None:
        while self.nbytes > self.max_bytes and len(self._frames) > 1:
            self.nbytes -= self._frames.popitem(last=False)[1].nbytes

    def __contains__(self, key: str) -> bool:
        return key in self._frames

    def __len__(self) -> int:
        return len(self._frames)

    def clear(self) -> None:
        self._frames.clear()
        self.nbytes = 0


# Temporary files older than this in a cache folder are from killed writes: a frame's write
# takes a second, and machines that share the folder may be writing theirs right now.
STALE_TMP_S = 15 * 60


class DiskCache:
    """One `<key>.npz` per frame in a folder; unreadable files count as absent. Opening it
    removes what killed writes left (io/atomic.py)."""

    def __init__(self, folder):
        self.folder = Path(folder)
        remove_stale_temporaries(self.folder, older_than_s=STALE_TMP_S)

    def path(self, key: str) -> Path:
        return self.folder / f"{key}.npz"

    def get(self, key: str) -> SplatFrame | None:
        """The frame stored under `key`, or None: absent, or failing its checks (then the
        file is deleted, so the frame is decoded and stored again)."""
        path = self.path(key)
        if not path.is_file():
            return None
        try:
            return read_frame(path)
        except InputError:
            path.unlink(missing_ok=True)
            return None

    def put(self, key: str, frame: SplatFrame) -> None:
        arrays = {**frame.arrays(), "resolution": np.int64(frame.resolution)}
        save_npz_atomic(self.path(key), **with_checksum(arrays))


_WIDTHS = {"means": (3,), "log_scales": (3,), "quats": (4,), "opacity_logits": (), "sh": None}
SH_WIDTHS = {(k, 3) for k in (1, 4, 9, 16)}  # SH degree 0..3
MAX_FRAME_BYTES = 1 << 30  # a frame of 60,000 Gaussians is 15 MB


def read_frame(path) -> SplatFrame:
    """A cache file, checked: its checksum (required: every cache file has one), keys,
    float32 arrays of one length, finite values. InputError otherwise."""
    arrays = read_npz(path, max_bytes=MAX_FRAME_BYTES)
    if KEY not in arrays:
        raise InputError(path, KEY, "missing (a cache file from before checksums)")
    verify(arrays, path)
    n = None
    for name, width in _WIDTHS.items():
        value = arrays.get(name)
        ok_width = value is not None and (
            value.shape[1:] in SH_WIDTHS if width is None else value.shape[1:] == width
        )
        if not ok_width or value.dtype != np.float32:
            expected = "(N, K, 3), K = 1, 4, 9 or 16" if width is None else f"(N, {width})"
            raise InputError(path, name, f"missing or not float32 {expected}")
        n = len(value) if n is None else n
        if len(value) != n:
            raise InputError(path, name, f"{len(value)} rows, 'means' has {n}")
        check_finite(value, path, name, along="Gaussian")
    resolution = arrays.get("resolution")
    if resolution is None or resolution.shape != () or resolution.dtype.kind not in "iu":
        raise InputError(path, "resolution", "missing or not an integer")
    if not 0 <= int(resolution) <= SIZE_LIMITS["s_max"]:  # 0: not decoded (SplatFrame)
        raise InputError(
            path,
            "resolution",
            f"{int(resolution)}: a UV resolution is in 0..{SIZE_LIMITS['s_max']}",
        )
    return SplatFrame(**{k: arrays[k] for k in _WIDTHS}, resolution=int(resolution))
