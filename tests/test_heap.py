"""heap.py: the allocator's free pages go back to the system (RSS falls), here under glibc's
malloc as in the bpy module (Debian's Blender 4.3 and 5.2 with their allocators: the UI
suite's tests/ui/blender/heap_release.py, which this runs in a fresh Python)."""

import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).parent / "ui" / "blender" / "heap_release.py"


@pytest.mark.skipif(sys.platform != "linux", reason="RSS is read from /proc")
def test_freed_holes_between_kept_arrays_go_back_to_the_system():
    """In a fresh process (a test process's heap is shaped by the tests before it)."""
    done = subprocess.run([sys.executable, str(SCRIPT)], capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    released = float(done.stdout.split("HEAP_RELEASED_MB ")[1].split()[0])
    assert released > 170, f"{released} MB of the 200 freed went back"


FAULTS = """
import resource, sys
import numpy as np
from archhead_addon.heap import keep_freed_memory
kept = keep_freed_memory() if sys.argv[1] == "keep" else None
def step():  # a training step's pattern: large blocks taken, then all freed together
    blocks = [np.ones(3_000_000, np.float32) for _ in range(4)]  # 12 MB each, written
    del blocks
step()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(10):
    step()
print(kept, (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 10)
"""


@pytest.mark.skipif(sys.platform != "linux", reason="glibc's malloc and its page-fault count")
def test_kept_freed_memory_is_taken_again_without_page_faults():
    """glibc's defaults hand the freed blocks back, and each step faults them in again;
    `keep_freed_memory` keeps them, so the steps after the first fault no page in."""
    faults = {}
    for mode in ("release", "keep"):
        done = subprocess.run(
            [sys.executable, "-c", FAULTS, mode], capture_output=True, text=True, check=True
        )
        kept, faults[mode] = done.stdout.split()
    assert kept == "True"
    assert float(faults["release"]) > 1000  # 12k pages a step, most faulted in again
    assert float(faults["keep"]) < 50
