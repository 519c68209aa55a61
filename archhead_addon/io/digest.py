"""A file's identity by its contents, across machines and renames."""

from __future__ import annotations

import hashlib


def file_digest(path) -> str:
    """sha1 of a file's contents, read in blocks (checkpoints run to hundreds of MB)."""
    h = hashlib.sha1()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()
