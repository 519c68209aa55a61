"""Handing memory that numpy freed back to the system.

A decode's temporaries (tens of MB on the decoding threads) are freed between the frames and
tables that stay, and the C allocator keeps such holes mapped: a crowd of 16 full-size
avatars held 100-130 MB of them after loading (7-8 MB a head, about its level tables' share).
Blender on Linux runs on glibc's malloc (the bpy module), jemalloc (Debian's 4.3) or TBB's
scalable allocator (Debian's 5.2), each with its own call that returns free pages; where
none is found (Windows) `release_free_memory` does nothing. `resident_mb` reads what the
process holds (the benchmarks' and tests' one reading of it).
"""

from __future__ import annotations

import ctypes
import functools
from pathlib import Path

ALL_ARENAS = b"arena.4096.purge"  # jemalloc >= 4.5: MALLCTL_ARENAS_ALL
CLEAN_ALL_BUFFERS = 0  # TBB's ScalableAllocationCmd TBBMALLOC_CLEAN_ALL_BUFFERS


@functools.cache
def _releases() -> tuple:
    """The calls that return free pages, of each allocator the process has: jemalloc's purge
    of every arena, TBB's scalable allocator's clean, glibc's malloc_trim (each harmless
    where another allocator serves malloc)."""
    try:
        process = ctypes.CDLL(None)
    except (OSError, TypeError):  # Windows has no global symbol table to open
        return ()
    calls = []
    mallctl = getattr(process, "mallctl", None)
    if mallctl is not None:
        mallctl.argtypes = [ctypes.c_char_p] + [ctypes.c_void_p] * 3 + [ctypes.c_size_t]
        calls.append(lambda: mallctl(ALL_ARENAS, None, None, None, 0))
    clean = getattr(process, "scalable_allocation_command", None)
    if clean is not None:
        clean.argtypes = [ctypes.c_int, ctypes.c_void_p]
        calls.append(lambda: clean(CLEAN_ALL_BUFFERS, None))
    trim = getattr(process, "malloc_trim", None)
    if trim is not None:
        trim.argtypes = [ctypes.c_size_t]
        calls.append(lambda: trim(0))
    return tuple(calls)


def release_free_memory() -> bool:
    """Return the allocators' free pages to the system; False where none can."""
    calls = _releases()
    for call in calls:
        call()
    return bool(calls)


def resident_mb(field: str = "VmRSS") -> float:
    """This process's resident memory now, MB (`field` "VmHWM": its peak so far); NaN where
    /proc/self/status cannot tell (not Linux)."""
    try:
        lines = Path("/proc/self/status").read_text().splitlines()
    except OSError:
        return float("nan")
    for line in lines:
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    return float("nan")
