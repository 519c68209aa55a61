"""Benchmark: import a long tracked sequence (default 1,000 frames, 100 expressions).

    python benchmarks/blender_import.py [--frames 1000] [--expressions 100]
    blender -b --python-exit-code 1 --python benchmarks/blender_import.py -- [--frames 1000]

Prints seconds for reading + building, the per-frame evaluation time of the rig, the scene's
memory (growth of resident memory across the import, each mode in a fresh process) and the
size of the saved, uncompressed .blend.
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys

import bpy
import numpy as np

from archhead_blender import api

MODES = ("DRIVERS", "KEYFRAMES", "NONE")


def main(argv):
    parser = argparse.ArgumentParser()
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--expressions", type=int, default=100)
    parser.add_argument("--mode", choices=MODES, help="measure one mode (in this process)")
    args = parser.parse_args(argv)
    if args.mode:
        print(measure(args.frames, args.expressions, args.mode))
        return
    print(
        "| frames | expressions | correctives | import s | frame change ms |"
        " scene memory MB | .blend MB |"
    )
    print("|---|---|---|---|---|---|---|")
    for mode in MODES:  # a fresh process each, so memory growth is the scene's alone
        out = subprocess.run(
            [
                sys.executable,
                __file__,
                "--frames",
                str(args.frames),
                "--expressions",
                str(args.expressions),
                "--mode",
                mode,
            ],
            check=True,
            capture_output=True,
            text=True,
        ).stdout
        print(next(line for line in out.splitlines() if line.startswith("| ")))


def measure(frames: int, expressions: int, mode: str) -> str:
    api.enable_addon()
    folder = api.scratch_folder("archhead_import_")
    path, warmup = folder / "bench.npz", folder / "warmup.npz"
    api.write_canonical(api.demo_sequence(frames), path)
    api.write_canonical(api.demo_sequence(5), warmup)
    bpy.ops.archhead.import_sequence(filepath=str(warmup))  # loads model and code, unmeasured
    bpy.ops.wm.read_homefile(use_empty=True)
    rss_before = _rss_mb()
    seconds = (
        api.time_calls(
            lambda: bpy.ops.archhead.import_sequence(
                filepath=str(path), n_expr=expressions, pose_correctives=mode
            ),
            1,
        ).min_ms
        / 1e3
    )
    scene_mb = _rss_mb() - rss_before
    scene = bpy.context.scene
    samples = np.linspace(scene.frame_start, scene.frame_end, 50).astype(int)
    per_frame = api.time_calls(
        lambda i: scene.frame_set(int(samples[i])), len(samples), with_index=True
    ).mean_ms
    blend = folder / "bench.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), compress=False)
    return (
        f"| {frames} | {expressions} | {mode.lower()} | {seconds:.2f} | {per_frame:.1f} | "
        f"{scene_mb:.0f} | {blend.stat().st_size / 2**20:.1f} |"
    )


def _rss_mb() -> float:
    """Resident memory now (the scene's cost is the growth across the import)."""
    with open("/proc/self/statm") as f:
        pages = int(f.read().split()[1])
    return pages * resource.getpagesize() / 2**20


if __name__ == "__main__":
    main(api.script_args(sys.argv))
