"""Decoded frames kept for playback: in memory (least recently used out, by bytes) and,
optionally, on disk as one npz per frame (written atomically, so render-farm machines can
share a cache folder and a crash never leaves a torn file).

A frame is named by `frame_key`: the avatar (checkpoint contents, identity, precision), the
codes and the level of detail, never the frame number, so an edit to any code makes a new
key and two frames with the same codes share one entry.
"""

from __future__ import annotations

import hashlib
import zipfile
from collections import OrderedDict
from pathlib import Path

import numpy as np

from ..io.atomic import remove_stale_temporaries, save_npz_atomic
from ..splat.frame import FIELDS, SplatFrame


def frame_key(avatar_digest: str, codes_digest: str, lod: float) -> str:
    """The cache name of one decoded frame."""
    h = hashlib.sha1(f"{avatar_digest}/{codes_digest}".encode())
    h.update(np.float64(lod).tobytes())
    return h.hexdigest()[:24]


class MemoryCache:
    """Least recently used frames out once their bytes pass the budget."""

    def __init__(self, max_bytes: int):
        self.max_bytes = int(max_bytes)
        self._frames: OrderedDict[str, SplatFrame] = OrderedDict()
        self.nbytes = 0

    def get(self, key: str) -> SplatFrame | None:
        frame = self._frames.get(key)
        if frame is not None:
            self._frames.move_to_end(key)
        return frame

    def put(self, key: str, frame: SplatFrame) -> None:
        if key in self._frames:
            self.nbytes -= self._frames.pop(key).nbytes
        self._frames[key] = frame
        self.nbytes += frame.nbytes
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
        path = self.path(key)
        if not path.is_file():
            return None
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {name: z[name] for name in FIELDS}
                return SplatFrame(**arrays, resolution=int(z["resolution"]))
        except (zipfile.BadZipFile, OSError, ValueError, KeyError, EOFError):
            return None

    def put(self, key: str, frame: SplatFrame) -> None:
        save_npz_atomic(self.path(key), **frame.arrays(), resolution=np.int64(frame.resolution))
