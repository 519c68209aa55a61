"""Where ArchHead keeps what it derives and fetches (UV layouts, landmark embeddings, the
compiled splat kernel, the real subject's media). Standard library only: the kernel's
builder runs under Blender's Python too."""

from __future__ import annotations

import os
from pathlib import Path


def cache_dir() -> Path:
    """$ARCHHEAD_CACHE, else ~/.cache/archhead."""
    return Path(os.environ.get("ARCHHEAD_CACHE") or Path.home() / ".cache" / "archhead")
