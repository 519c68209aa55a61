"""The add-on hands freed memory back to the system under this Python's allocator (Debian's
Blender 4.3: jemalloc; 5.2: TBB's scalable allocator; plain Python and the bpy module:
glibc's malloc, tests/test_heap.py): a decode's pattern of temporaries freed between arrays
that stay, then `release_free_memory`. Prints HEAP_RELEASED_MB, the best of three rounds.

    blender -b --python heap_release.py        python heap_release.py
"""

import numpy as np

from archhead_addon.heap import release_free_memory, resident_mb


def released_mb() -> float:
    big = np.ones(20 << 18, np.float32)
    del big
    kept, freed = [], []
    for _ in range(200):
        freed.append(np.ones(1 << 18, np.float32))  # 1 MB, touched
        kept.append(np.ones(1 << 12, np.float32))
    before = resident_mb()
    del freed
    if not release_free_memory():
        raise SystemExit("no allocator call found to release free memory")
    return before - resident_mb()


# The best of three rounds: Blender's own threads may still be allocating as a loaded
# machine starts it (one CI round on 4.3 read 157 MB; a quiet one reads 201 every round).
print(f"HEAP_RELEASED_MB {max(released_mb() for _ in range(3)):.0f}")
