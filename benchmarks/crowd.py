"""Benchmark: many avatars in one scene, the scene continuous LOD is for.

    python benchmarks/crowd.py [--heads 4,16,64] [--avatars demo,full] [--size 1280x720]
                               [--frames 3] [--json FILE]

For each head count N and avatar size, a fresh process (2 BLAS / OpenMP threads) builds the
crowd as a user's script would: the demo head imported and its avatar loaded once, then
duplicated (Shift+D of head, rig and avatar) N - 1 times and spread from 0.5 to 30 m in front
of the camera, each avatar's level of detail driven by its distance (near 0.5 m, far 30 m).
The avatars are untrained ones of the "demo" preset's size and of full size (their decode
costs equal trained ones'). Then it measures, each over --frames frames not seen before:

- RSS after the first head and after all N (the cost of one more head);
- a frame change (handlers decoding every avatar) with the distance-driven levels and with
  every avatar held at LOD 0, and their ratio;
- Decode Frames over the whole crowd (one pass), per head and frame;
- the handler on frames already decoded: per head with nothing to change, and per head
  showing a cached frame;
- an exact render of one frame at --size (the default culling: "Renders"), driven and LOD 0.

Prints a markdown table (and --json: the rows).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

NEAR, FAR = 0.5, 30.0


def _rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _build(n: int, checkpoint: Path, folder: Path, size: tuple[int, int]):
    import bpy
    import numpy as np

    from archhead_blender import api

    bpy.ops.wm.read_homefile(use_empty=True)
    api.write_canonical(api.demo_sequence(frames=40), folder / "demo.npz")
    bpy.ops.archhead.import_sequence(filepath=str(folder / "demo.npz"))
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = size
    head = bpy.data.objects["demo"]
    bpy.context.view_layer.objects.active = head
    if bpy.ops.archhead.load_avatar(filepath=str(checkpoint)) != {"FINISHED"}:
        raise SystemExit(f"could not load {checkpoint}")
    avatar = bpy.data.objects["demo_avatar"]
    rig = head.parent
    camera = scene.camera
    scene.frame_set(0)
    rss_first = _rss_mb()
    cam = np.array(camera.matrix_world)
    forward = -cam[:3, 2]  # Blender cameras look down their -Z
    right = cam[:3, 0]
    start = np.array(rig.matrix_world)[:3, 3]
    d0 = np.linalg.norm(start - cam[:3, 3])
    originals = (head, rig, avatar)
    rigs = [rig]
    for i in range(1, n):
        bpy.ops.object.select_all(action="DESELECT")
        for obj in originals:
            obj.select_set(True)
        bpy.context.view_layer.objects.active = head
        bpy.ops.object.duplicate(linked=False)
        new_rig = next(o for o in bpy.context.selected_objects if o.type == "ARMATURE")
        t = i / max(n - 1, 1)
        distance = NEAR * (FAR / NEAR) ** t  # evenly spread in log distance
        side = (-1) ** i * 0.25 * distance * ((i % 4) / 4)  # spread across the view
        offset = forward * (distance - d0) + right * side
        new_rig.location = (start + offset).tolist()
        rigs.append(new_rig)
    avatars = api.scene_avatars(scene)
    for obj in avatars:
        api.drive_lod_by_distance(obj, camera, NEAR, FAR)
    bpy.context.view_layer.update()
    return scene, avatars, rss_first, _rss_mb()


def measure(n: int, kind: str, frames: int, size: tuple[int, int]) -> dict:
    import bpy

    from archhead_blender import api
    from archhead_blender.handlers import refresh_scene

    api.enable_addon()
    folder = api.scratch_folder("archhead_crowd_")
    checkpoint = folder / f"avatar_{kind}.npz"
    python = api.python_with_torch() or sys.executable
    command = [python, "-m", "archhead_addon.avatar.untrained", str(checkpoint)]
    subprocess.run(command + (["--preset", "demo"] if kind == "demo" else []), check=True)
    watch = api.Stopwatch()
    scene, avatars, rss_first, rss_all = _build(n, checkpoint, folder, size)
    built_s = watch.seconds
    context = bpy.context
    sessions = [api.session(obj) for obj in avatars]
    frame = iter(range(1, 40))

    def frame_change() -> float:
        f = next(frame)
        start = time.perf_counter()
        scene.frame_set(f)
        return 1e3 * (time.perf_counter() - start)

    def gaussians() -> int:
        return sum(len(obj.data.vertices) for obj in avatars)

    driven_ms = min(frame_change() for _ in range(frames))
    driven_count = gaussians()
    for s in sessions:
        s.lod_override = 0.0
    lod0_ms = min(frame_change() for _ in range(frames))
    lod0_count = gaussians()
    for s in sessions:
        s.lod_override = None
    decode_frames = [next(frame) for _ in range(frames)]
    start = time.perf_counter()
    api.decode_frames(context, avatars, decode_frames)
    decode_ms = 1e3 * (time.perf_counter() - start) / (n * frames)
    # the handler on decoded frames: showing a cached frame, then with nothing to change
    scene.frame_set(decode_frames[0])
    depsgraph = context.evaluated_depsgraph_get()
    start = time.perf_counter()
    scene.frame_set(decode_frames[1])
    cached_ms = 1e3 * (time.perf_counter() - start) / n
    depsgraph = context.evaluated_depsgraph_get()
    idle = api.time_calls(lambda: refresh_scene(scene, depsgraph), 5).median_ms / n
    out = Path(api.scratch_folder("archhead_crowd_render_"))
    renders = {}
    for name, lod in (("driven", None), ("lod0", 0.0)):
        f = next(frame)
        start = time.perf_counter()
        api.render_frames(context, [f], out / name, lod=lod, exact=True)
        renders[name] = time.perf_counter() - start
    return {
        "heads": n,
        "avatar": kind,
        "build_s": round(built_s, 1),
        "rss_first_mb": round(rss_first),
        "rss_all_mb": round(rss_all),
        "mb_per_extra_head": round((rss_all - rss_first) / max(n - 1, 1), 1),
        "gaussians_driven": driven_count,
        "gaussians_lod0": lod0_count,
        "frame_change_ms_driven": round(driven_ms),
        "frame_change_ms_lod0": round(lod0_ms),
        "decode_ms_per_head_frame": round(decode_ms, 1),
        "handler_ms_per_head_cached": round(cached_ms, 2),
        "handler_ms_per_head_idle": round(idle, 3),
        "render_s_driven": round(renders["driven"], 2),
        "render_s_lod0": round(renders["lod0"], 2),
        "last_render": str(out / "driven"),
    }


def table(rows: list[dict]) -> str:
    lines = [
        "| N | avatar | Gaussians driven / LOD 0 | frame change ms driven / LOD 0 (ratio) "
        "| Decode Frames ms per head-frame | handler ms per head: cached frame / idle "
        "| exact render s driven / LOD 0 | RSS first head / all, MB per extra head |",
        "|---:|---|---:|---|---:|---|---|---|",
    ]
    for r in rows:
        ratio = r["frame_change_ms_driven"] / max(r["frame_change_ms_lod0"], 1)
        lines.append(
            f"| {r['heads']} | {r['avatar']} | {r['gaussians_driven']:,} / "
            f"{r['gaussians_lod0']:,} | {r['frame_change_ms_driven']} / "
            f"{r['frame_change_ms_lod0']} ({ratio:.2f}x) | {r['decode_ms_per_head_frame']} | "
            f"{r['handler_ms_per_head_cached']} / {r['handler_ms_per_head_idle']} | "
            f"{r['render_s_driven']} / {r['render_s_lod0']} | {r['rss_first_mb']} / "
            f"{r['rss_all_mb']} MB, {r['mb_per_extra_head']} |"
        )
    return "\n".join(lines)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--heads", default="4,16,64")
    parser.add_argument("--avatars", default="demo,full")
    parser.add_argument("--size", default="1280x720")
    parser.add_argument("--frames", type=int, default=3)
    parser.add_argument("--json", type=Path)
    parser.add_argument("--one", help=argparse.SUPPRESS)  # N,kind: measure in this process
    args = parser.parse_args(argv)
    size = tuple(int(v) for v in args.size.split("x"))
    if args.one:
        from archhead_addon.timing import restart_with_threads

        restart_with_threads(2)  # before bpy and numpy load their thread pools
        n, kind = args.one.split(",")
        print("ROW " + json.dumps(measure(int(n), kind, args.frames, size)), flush=True)
        return
    rows = []
    for kind in args.avatars.split(","):
        for n in (int(v) for v in args.heads.split(",")):
            command = [sys.executable, __file__, "--one", f"{n},{kind}"]
            command += ["--frames", str(args.frames), "--size", args.size]
            done = subprocess.run(command, capture_output=True, text=True)
            row = [line for line in done.stdout.splitlines() if line.startswith("ROW ")]
            if done.returncode or not row:
                print(done.stdout[-3000:], done.stderr[-3000:], file=sys.stderr)
                raise SystemExit(f"crowd of {n} {kind} avatars failed ({done.returncode})")
            rows.append(json.loads(row[0][4:]))
            print(table(rows[-1:]).splitlines()[-1], flush=True)
    print(table(rows))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
