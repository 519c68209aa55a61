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
