"""Handing memory that numpy freed back to the system, or keeping it where a process frees
and takes the same memory over and over.

A decode's temporaries (tens of MB on the decoding threads) are freed between the frames and
tables that stay, and the C allocator keeps such holes mapped: a crowd of 16 full-size
avatars held 100-130 MB of them after loading (7-8 MB a head, about its level tables' share).
Blender on Linux runs on glibc's malloc (the bpy module), jemalloc (Debian's 4.3) or TBB's
scalable allocator (Debian's 5.2), each with its own call that returns free pages; where
none is found (Windows) `release_free_memory` does nothing. `resident_mb` reads what the
process holds (the benchmarks' and tests' one reading of it).

Training is the other case: every step frees and allocates again the same tens of MB
(the decoder's activations, 11.5 MB each at LOD 0). glibc maps blocks above a threshold on
their own and unmaps them when freed; it raises the threshold when it sees such a block
freed, but a resumed run's process kept the default and took the blocks again page by page
every step (2,000-7,000 page faults a stage-1 step, 1.18x its time).
`keep_freed_memory` keeps them in every process (benchmarks/freed_memory.py).
"""

from __future__ import annotations

import ctypes
import functools
from pathlib import Path

M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3  # glibc's mallopt parameters
MMAP_THRESHOLD_MAX = 32 << 20  # the largest glibc takes on 64-bit systems
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


def keep_freed_memory() -> bool:
    """Make glibc's malloc keep freed memory for the next allocation: blocks up to 32 MB
    come from the heap rather than from mappings of their own (which go back to the system
    when freed), and the heap's free top is not trimmed. For a long run of alike steps
    (training, tracking); its peak RSS is what it holds from then on. False where malloc is
    not glibc's (nothing changed)."""
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, TypeError, AttributeError):  # Windows, macOS: another malloc
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    kept = mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_MAX) == 1
    return mallopt(M_TRIM_THRESHOLD, 2**31 - 1) == 1 and kept


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
