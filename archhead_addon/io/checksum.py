"""A checksum of an npz's arrays, stored beside them (key `checksum`): files ArchHead writes
for itself (avatar checkpoints, decode-cache frames) are checked against it when read back,
so a damaged file is refused (or re-made) instead of shown. Files from before it have no
such key and are read as they are."""

from __future__ import annotations

import hashlib

import numpy as np

from .errors import InputError

KEY = "checksum"


def content_checksum(arrays: dict) -> str:
    """sha256 over every array's key, dtype, shape and bytes, in key order (KEY excluded)."""
    h = hashlib.sha256()
    for key in sorted(k for k in arrays if k != KEY):
        a = np.ascontiguousarray(arrays[key])
        h.update(f"{key}\0{a.dtype.str}\0{a.shape}\0".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def with_checksum(arrays: dict) -> dict:
    return {**arrays, KEY: np.str_(content_checksum(arrays))}


def verify(arrays: dict, path) -> bool:
    """True when the stored checksum matches, False when there is none (an older file);
    InputError when it does not match."""
    if KEY not in arrays:
        return False
    stored = arrays[KEY]
    if stored.shape != () or stored.dtype.kind != "U" or str(stored) != content_checksum(arrays):
        raise InputError(path, KEY, "does not match the file's content: the file is damaged")
    return True
