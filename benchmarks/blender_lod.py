"""Benchmark: what a change of the avatar's level of detail costs in Blender.

    python benchmarks/blender_lod.py [--repeats 10] [--checkpoint AVATAR.npz]
                                  [--sweep STEP --json FILE]

Runs with 2 BLAS / OpenMP threads (restarting itself with them set). Imports the demo head,
loads an avatar (the checkpoint given, else an untrained one of the built-in model, which
needs torch to create; the decode cost does not depend on the weights), then times, per
change: the slider moved within one UV resolution (its tables cached), the first visit of a
resolution (tables built), a scrub across the whole range, and a frame change served from
the memory cache. "total" is the property change to an evaluated depsgraph: handler (decode
+ writing the points) and Geometry Nodes instancing. Prints a markdown table. With --sweep,
times only "total" at l = 0, STEP, ..., 1 (each resolution's tables built first) and writes
them to the --json file (the report of `python -m benchmarks.error_vs_time` reads it).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import bpy

from archhead_blender import api


def _ms(fn, repeats: int) -> float:
    """Median milliseconds of fn(i) over i = 0 .. repeats - 1."""
    return api.time_calls(fn, repeats, with_index=True).median_ms


def main(argv) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--checkpoint", help="avatar checkpoint (default: an untrained one)")
    parser.add_argument(
        "--sweep", type=float, help="time LOD changes at every multiple of this step only"
    )
    parser.add_argument("--json", help="with --sweep: the file to write the timings to")
    args = parser.parse_args(argv)
    if (args.sweep is None) != (args.json is None):
        parser.error("--sweep and --json go together")

    api.enable_addon()
    folder = api.scratch_folder("archhead_lod_")
    checkpoint = (
        Path(args.checkpoint)
        if args.checkpoint
        else api.untrained_checkpoint(folder / "untrained.npz")
    )
    bpy.ops.wm.read_homefile(use_empty=True)
    api.write_canonical(api.demo_sequence(frames=30), folder / "demo.npz")
    bpy.ops.archhead.import_sequence(filepath=str(folder / "demo.npz"))
    head = bpy.data.objects["demo"]
    bpy.context.view_layer.objects.active = head
    bpy.ops.archhead.load_avatar(filepath=str(checkpoint))
    obj = bpy.data.objects["demo_avatar"]
    runtime = api.session(obj).runtime
    settings = obj.archhead_avatar
    view_layer = bpy.context.view_layer

    def set_lod(value):
        settings.lod = value
        view_layer.update()

    fresh = iter(range(1, 10**6))

    def near(lod):
        """A value not shown before (no cached frame) with the resolution of `lod`."""
        return lod + (1e-6 if lod == 0.0 else -1e-6) * next(fresh)

    if args.sweep is not None:
        rows = []
        for i in range(round(1 / args.sweep) + 1):
            lod = round(i * args.sweep, 6)
            set_lod(lod)  # builds this resolution's tables
            total = _ms(lambda i, lod=lod: set_lod(near(lod)), args.repeats)
            rows.append(
                {
                    "lod": lod,
                    "resolution": runtime.resolution(lod),
                    "points": len(obj.data.vertices),
                    "update_ms": total,
                }
            )
        Path(args.json).write_text(json.dumps(rows, indent=1))
        return

    rows = []
    for lod in (0.0, 1.0):
        size = api.resolution_for_lod(lod)[1]
        set_lod(lod)  # builds this resolution's tables
        total = _ms(lambda i, lod=lod: set_lod(near(lod)), args.repeats)
        codes = api.frame_codes(
            head, bpy.context.evaluated_depsgraph_get(), api.session(obj).joint_dirs
        )
        kwargs = codes.as_kwargs()
        decode = _ms(lambda i, lod=lod, kw=kwargs: runtime.decode(lod, **kw), args.repeats)
        frame = api.session(obj).frame(codes, lod)[1]
        attrs = api.point_attributes(frame)
        write = _ms(lambda i, a=attrs: api.write_points(obj, a), args.repeats)

        def first_visit(i, lod=lod):
            runtime.level.clear()
            set_lod(near(lod))

        build = _ms(first_visit, max(args.repeats // 2, 2))
        rows.append((lod, size, len(obj.data.vertices), total, decode, write, build))

    set_lod(0.0)
    scrub_values = [i / 20 for i in range(21)]
    scrub = _ms(lambda i: set_lod(scrub_values[i % len(scrub_values)]), len(scrub_values))
    playback = {}
    for lod in (0.0, 1.0):
        set_lod(lod)
        for frame in range(1, 6):  # fill the memory cache
            bpy.context.scene.frame_set(frame)
        playback[lod] = _ms(lambda i: bpy.context.scene.frame_set(1 + i % 5), 10)

    print(
        "| l | S | Gaussians | LOD change total ms | decode ms | write points ms "
        "| first visit of S ms | cached frame change ms |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|---:|")
    for lod, size, count, total, decode, write, build in rows:
        print(
            f"| {lod:.0f} | {size} | {count:,} | {total:.0f} | {decode:.0f} | {write:.1f} "
            f"| {build:.0f} | {playback[lod]:.0f} |"
        )
    print(
        f"\nScrubbing the slider 0 -> 1 in steps of 0.05 (a new S at every step): "
        f"{scrub:.0f} ms per change (median)"
    )


if __name__ == "__main__":
    api.restart_with_threads(2)
    main(api.script_args(sys.argv))
