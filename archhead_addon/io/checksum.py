"""A checksum of a file's content, stored beside it (key `checksum`): files ArchHead writes
for itself (avatar checkpoints, decode-cache frames: npz; training states: torch.save) are
checked against it when read back, so a damaged or edited file is refused (or re-made)
instead of used. Files from before it have no such key; their readers say what they do."""

from __future__ import annotations

import hashlib
import struct

import numpy as np

from .errors import InputError

KEY = "checksum"


def _array(h, a: np.ndarray) -> None:
    a = np.ascontiguousarray(a)
    h.update(f"{a.dtype.str}\0{a.shape}\0".encode())
    h.update(a)  # the array's own buffer: tobytes() would copy it


def content_checksum(arrays: dict) -> str:
    """sha256 over every array's key, dtype, shape and bytes, in key order (KEY excluded)."""
    h = hashlib.sha256()
    for key in sorted(k for k in arrays if k != KEY):
        h.update(f"{key}\0".encode())
        _array(h, arrays[key])
    return h.hexdigest()


def tree_checksum(tree: dict) -> str:
    """sha256 of a nested value as a pickle holds it (a training state): dicts in the order
    of their keys' encodings, so insertion order does not count; lists, tuples, sets, text,
    numbers, None, and arrays as content_checksum hashes them. The top level's KEY excluded.
    TypeError on anything else."""
    h = hashlib.sha256()
    _node(h, {k: v for k, v in tree.items() if k != KEY})
    return h.hexdigest()


def _encoded(value) -> bytes:
    h = hashlib.sha256()
    _node(h, value)
    return h.digest()


def _node(h, value) -> None:
    """Each value tagged with its type, containers with their length, so that no two
    different trees hash the same bytes."""
    if isinstance(value, np.ndarray | np.generic):
        h.update(b"a")
        _array(h, np.asarray(value))
    elif isinstance(value, dict):
        h.update(b"d%d\0" % len(value))
        for key, item in sorted((_encoded(k), v) for k, v in value.items()):
            h.update(key)
            _node(h, item)
    elif isinstance(value, list | tuple):
        h.update(b"%s%d\0" % (b"l" if isinstance(value, list) else b"t", len(value)))
        for item in value:
            _node(h, item)
    elif isinstance(value, set | frozenset):
        h.update(b"S%d\0" % len(value) + b"".join(sorted(_encoded(v) for v in value)))
    elif isinstance(value, str):
        data = value.encode("utf-8", "surrogatepass")
        h.update(b"s%d\0" % len(data) + data)
    elif isinstance(value, bytes | bytearray):
        h.update(b"b%d\0" % len(value) + bytes(value))
    elif value is None or isinstance(value, bool):
        h.update(b"N" if value is None else b"T" if value else b"F")
    elif isinstance(value, int):
        h.update(b"i%d\0" % value)
    elif isinstance(value, float):
        h.update(b"f" + struct.pack("<d", value))
    elif isinstance(value, complex):
        h.update(b"c" + struct.pack("<dd", value.real, value.imag))
    else:
        raise TypeError(f"a {type(value).__name__} is not a value a checksum covers")


def with_checksum(arrays: dict) -> dict:
    return {**arrays, KEY: np.str_(content_checksum(arrays))}


def verify(content: dict, path, checksum=content_checksum) -> bool:
    """True when the stored checksum is `checksum(content)` (content_checksum: an npz's
    arrays; tree_checksum: a pickled tree), False when there is none (an older file);
    InputError when it does not match."""
    if KEY not in content:
        return False
    stored = content[KEY]
    if isinstance(stored, np.ndarray):  # an npz's text: a 0-d array
        stored = str(stored) if stored.shape == () and stored.dtype.kind == "U" else None
    try:
        ok = isinstance(stored, str) and stored == checksum(content)
    except TypeError as exc:
        raise InputError(path, KEY, f"cannot be checked: {exc}") from exc
    if not ok:
        raise InputError(
            path, KEY, "does not match the file's content: the file is damaged or was edited"
        )
    return True
