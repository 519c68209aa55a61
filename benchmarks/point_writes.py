"""Benchmark: what showing a decoded frame costs Blender, and a layout that was tried instead.

    python benchmarks/point_writes.py [--heads 16] [--rounds 3]

1. `point_instances.write_points` alone, in a scene of --heads point objects: the time per
   object for 10, 4,000, 16,000 and 60,000 points (each object rewritten, the scene evaluated
   between passes, as playback does), and the fixed and per-point parts fitted to them.
2. The crowd of `crowd.py` (--heads full-size heads, screen-size levels) on frames already
   decoded, two ways in turn, --rounds rounds of 12 frame changes each:
   - **writes**, the add-on as it is: the handler writes each head's points into its mesh;
   - **swaps**: each head's points of each frame prebuilt as a mesh of its own, and the
     head's object given that mesh (`obj.data = mesh`), the add-on paused.
   Per way: the add-on's part of a frame change per head (the handler, or the loop of
   assignments), Blender's evaluation after it, and the whole frame change.

Prints Markdown tables.
"""

from __future__ import annotations

import argparse
import statistics
import time

POINT_COUNTS = (10, 4_000, 16_000, 60_000)


def writes_alone(n_objects: int) -> list[tuple[int, float]]:
    """(points, ms per object) of write_points in a scene of n_objects point objects."""
    import bpy
    import numpy as np

    from archhead_blender.point_instances import create_point_object, write_points

    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    rig = bpy.data.objects.new("rig", None)
    scene.collection.objects.link(rig)
    objects = [create_point_object(f"points_{i}", rig, scene.collection) for i in range(n_objects)]
    rng = np.random.default_rng(0)
    rows = []
    for n in POINT_COUNTS:
        frame = {
            "position": rng.random((n, 3), np.float32),
            "scale": 0.01 * rng.random((n, 3), np.float32),
            "rotation": rng.random((n, 4), np.float32),
            "opacity": rng.random(n, np.float32),
            "colour": rng.random((n, 4), np.float32),
        }
        times = []
        for _ in range(15):
            start = time.perf_counter()
            for obj in objects:
                write_points(obj, frame)
            times.append(1e3 * (time.perf_counter() - start) / n_objects)
            bpy.context.evaluated_depsgraph_get()  # the evaluated scene shares the arrays
        rows.append((n, statistics.median(times)))
    return rows


def crowd_ways(heads: int, rounds: int) -> dict[str, dict[str, float]]:
    """Medians of {way: {"addon": ms per head, "evaluation": ms, "frame": ms}}."""
    import bpy
    import crowd

    from archhead_blender import api
    from archhead_blender.handlers import refresh_scene, resume, suspend

    folder = api.scratch_folder("archhead_point_writes_")
    checkpoint = crowd.untrained_checkpoint(folder, "full")
    scene, avatars, _ = crowd._build(heads, checkpoint, folder, (1280, 720))
    context = bpy.context
    frames = list(range(2, 8))
    api.decode_frames(context, avatars, frames)
    prebuilt = {}
    for f in frames:
        scene.frame_set(f)  # the handler writes each head's points of frame f
        for obj in avatars:
            prebuilt[obj.name, f] = obj.data.copy()

    def change(f: int, way: str) -> tuple[float, float, float]:
        start = time.perf_counter()
        suspend()
        try:
            scene.frame_set(f)  # Blender's part: rigs, keys, drivers
        finally:
            resume()
        depsgraph = context.evaluated_depsgraph_get()
        begin = time.perf_counter()
        if way == "writes":
            refresh_scene(scene, depsgraph)
        else:
            for obj in avatars:
                obj.data = prebuilt[obj.name, f]
        end = time.perf_counter()
        context.evaluated_depsgraph_get()  # Blender evaluates the new points
        done = time.perf_counter()
        return 1e3 * (end - begin) / heads, 1e3 * (done - end), 1e3 * (done - start)

    samples: dict[str, list] = {"writes": [], "swaps": []}
    for _ in range(rounds):
        for way in samples:
            samples[way] += [change(f, way) for f in frames * 2]
        for obj in avatars:  # back to the add-on's own meshes, then on to the next round
            obj.data = obj.data.copy()
            api.session(obj).shown = None
    return {
        way: {
            key: statistics.median(s[k] for s in rows)
            for k, key in enumerate(("addon", "evaluation", "frame"))
        }
        for way, rows in samples.items()
    }


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--heads", type=int, default=16)
    p.add_argument("--rounds", type=int, default=3)
    args = p.parse_args(argv)
    from archhead_addon.timing import restart_with_threads

    restart_with_threads(2)  # before bpy and numpy load their thread pools
    from archhead_blender import api

    api.enable_addon()
    rows = writes_alone(args.heads)
    print(f"write_points, {args.heads} point objects (ms per object, median of 15 passes):\n")
    print("| points | ms |\n|---:|---:|")
    for n, ms in rows:
        print(f"| {n:,} | {ms:.3f} |")
    (n0, t0), (n1, t1) = rows[0], rows[-1]
    per_point = (t1 - t0) / (n1 - n0)
    print(f"\nfixed {t0 - per_point * n0:.3f} ms, {1e6 * per_point:.1f} ns a point\n")
    ways = crowd_ways(args.heads, args.rounds)
    print(f"{args.heads} full-size heads on decoded frames ({args.rounds} rounds, medians):\n")
    print("| way | add-on ms per head | Blender's evaluation after it, ms | frame change, ms |")
    print("|---|---:|---:|---:|")
    for way, m in ways.items():
        print(f"| {way} | {m['addon']:.3f} | {m['evaluation']:.1f} | {m['frame']:.1f} |")


if __name__ == "__main__":
    main()
