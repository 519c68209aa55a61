"""Atomic file writes: write a temporary file beside the target, fsync, then rename over it.

A process killed mid-write leaves its temporary file (`.NAME.XXXXXXXX.tmp`) behind, never a
torn target; whoever opens the folder next removes those (`remove_stale_temporaries`).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

TMP_SUFFIX = ".tmp"


@contextlib.contextmanager
def atomic_path(target) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; on success it replaces the target.

    A crash at any point leaves either the old file or the new one, never a torn file.
    """
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=TMP_SUFFIX, dir=target.parent)
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp's 0600 would hide shared caches from other users
    tmp = Path(tmp)
    try:
        yield tmp
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, target)
        _fsync_dir(target.parent)
    finally:
        tmp.unlink(missing_ok=True)


def _fsync_dir(folder: Path) -> None:
    with contextlib.suppress(OSError):  # not every filesystem allows opening a directory
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def write_bytes_atomic(target, data: bytes) -> None:
    with atomic_path(target) as tmp:
        tmp.write_bytes(data)


def save_npz_atomic(target, **arrays) -> None:
    """np.savez to `target` atomically (the name is kept exactly; numpy adds no suffix)."""
    import numpy as np

    with atomic_path(target) as tmp, open(tmp, "wb") as f:
        np.savez(f, **arrays)


def remove_stale_temporaries(folder, older_than_s: float = 0.0) -> list[Path]:
    """Delete the temporary files that killed atomic writes left in `folder`, those older
    than `older_than_s`: a folder that others write to at the same time (a cache shared by
    render-farm machines) passes a margin that spares their writes in flight. Returns what
    was removed; a missing folder has nothing to remove."""
    folder, removed, now = Path(folder), [], time.time()
    for path in folder.glob(f".*{TMP_SUFFIX}") if folder.is_dir() else ():
        try:
            if path.is_file() and now - path.stat().st_mtime >= older_than_s:
                path.unlink()
                removed.append(path)
        except OSError:  # removed meanwhile by its writer, or not ours to delete
            continue
    return removed
