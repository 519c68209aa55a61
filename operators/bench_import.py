"""Benchmark: import a long tracked sequence (default 1,000 frames, 100 expressions).

    python operators/bench_import.py [--frames 1000] [--expressions 100]
    blender -b --python operators/bench_import.py -- [--frames 1000]

Prints seconds for reading + building, the per-frame evaluation time of the rig and the
scene's memory (growth of resident memory across the import, and the peak).
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
from pathlib import Path

import bpy
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from archhead_addon.sequences import write_canonical  # noqa: E402
from archhead_addon.sequences.demo import demo_sequence  # noqa: E402
from operators.script_import import enable_addon  # noqa: E402


def main(argv):
    parser = argparse.ArgumentParser()
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--expressions", type=int, default=100)
    args = parser.parse_args(argv)
    enable_addon()
    path = Path(tempfile.mkdtemp()) / "bench.npz"
    write_canonical(demo_sequence(args.frames), path)
    print("| frames | expressions | correctives | import s | frame change ms |"
          " scene memory MB | peak RSS MB |")
    print("|---|---|---|---|---|---|---|")
    for mode in ("DRIVERS", "KEYFRAMES", "NONE"):
        bpy.ops.wm.read_homefile(use_empty=True)
        rss_before = _rss_mb()
        start = time.perf_counter()
        bpy.ops.archhead.import_sequence(filepath=str(path), n_expr=args.expressions,
                                         pose_correctives=mode)
        seconds = time.perf_counter() - start
        scene_mb = _rss_mb() - rss_before
        scene = bpy.context.scene
        samples = np.linspace(scene.frame_start, scene.frame_end, 50).astype(int)
        start = time.perf_counter()
        for frame in samples:
            scene.frame_set(int(frame))
        per_frame = (time.perf_counter() - start) / len(samples) * 1000
        peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        print(f"| {args.frames} | {args.expressions} | {mode.lower()} | {seconds:.2f} | "
              f"{per_frame:.1f} | {scene_mb:.0f} | {peak_mb:.0f} |")


def _rss_mb() -> float:
    """Resident memory now (the scene's cost is the growth across the import)."""
    with open("/proc/self/statm") as f:
        pages = int(f.read().split()[1])
    return pages * resource.getpagesize() / 2**20


if __name__ == "__main__":
    main(sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:])
