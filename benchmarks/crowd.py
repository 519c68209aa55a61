"""Benchmark: many avatars in one scene, the scene continuous LOD is for.

    python benchmarks/crowd.py [--heads 4,16,64] [--avatars demo,full] [--size 1280x720]
                               [--frames 5] [--memory-total MB] [--json FILE]
                               [--picture PNG --checkpoint AVATAR.npz [--picture-heads 16]]

For each head count N and avatar size, a fresh process (2 BLAS / OpenMP threads) builds the
crowd as a user's script would: N talking heads imported (the demo sequence, each started at
another frame, so that no two say the same thing), the avatar loaded on the first, then on
all the others at once (one Load Avatar with them selected), the heads spread from 0.5 to
30 m in front of the camera, each avatar's level of detail driven by its size on screen
(S_max at 0.5 m, S_min from 2 m: the same Gaussians per pixel of a head at any distance).
The avatars are untrained ones of the "demo" preset's size and of full size (their decode
costs equal trained ones'). Then it measures, each over --frames frames not seen before:

- RSS: one head with its avatar, and what each further head adds, by its import and by its
  avatar (all heads are imported first, then the avatars load);
- a frame change (handlers decoding every avatar; the median over the frames) with the
  distance-driven levels and with every avatar held at LOD 0, frame by frame in turn, and
  their ratio; and with the add-on paused (Blender evaluating the rigs alone: the part no
  level of detail changes), and paused with each head's shape evaluated from its keys
  (what Load Avatar's pinning of the Basis saves);
- the heads' decodes alone at one frame, as a frame change runs them: every head at LOD 1,
  0.5 and 0, fitted as a fixed part and a cost per texel, and at the driven levels (a second
  table: what the fixed part costs the driven/LOD-0 ratio);
- Decode Frames over the whole crowd (one pass), per head and frame;
- the add-on's handler on frames already decoded, per head: showing a cached frame (its
  codes read from the rig, the frame found, its points written), and with nothing to change;
- an exact render of one frame at --size (the default culling: "Renders"), driven and LOD 0;
- memory after playing the frames left with every avatar at LOD 0 (the most a frame takes):
  the decoded frames the memory caches keep (within the preferences' memory for all avatars,
  --memory-total to set it), RSS then and the run's peak.

Prints a markdown table (and --json: the rows). --picture also renders a crowd of a trained
avatar (--checkpoint; the untrained ones draw no face) and writes the driven render there.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

from archhead_addon.heap import resident_mb

NEAR, FAR = 0.5, 30.0  # where the heads stand
# The driver: by screen size, S_max at 0.5 m and S_min at 4 x that (the same Gaussians per
# pixel of a head everywhere; docs/blender_avatar.md, "Level of detail")
DRIVE_NEAR, DRIVE_FAR = 0.5, 2.0


def _sequence(folder: Path, i: int, offset: bool = True) -> Path:
    """The demo talking head, its motion started i x 7 frames later (looped) and its
    expressions offset by a constant of its own: no two heads of the crowd show the same
    codes at any frame, so none shares another's decoded frames."""
    from dataclasses import replace

    import numpy as np

    from archhead_blender import api

    seq = api.demo_sequence(frames=40)
    rolled = {k: np.roll(getattr(seq, k), -7 * i, axis=0) for k in ROLLED}
    if offset:  # (a picture leaves it out: a trained avatar draws the tracked expressions)
        rolled["expr"] = rolled["expr"] + np.random.default_rng(i).normal(0, 0.3, seq.expr.shape[1])
    path = folder / f"head_{i:02d}.npz"
    api.write_canonical(replace(seq, **rolled), path)
    return path


ROLLED = ("expr", "jaw", "neck", "eyes", "rotation")


def _build(n: int, checkpoint: Path, folder: Path, size: tuple[int, int], picture=False):
    """The crowd (module docstring); returns (scene, avatars, RSS in MB: one head with its
    avatar, what each further head adds by its import and by its avatar). The heads are all
    imported before any avatar loads, so that neither part reuses memory the other freed.
    Each avatar figure is read once the scene has settled: after one more refresh, which
    any edit, click or frame change brings, and which returns the free pages that Blender's
    evaluation of the new points left (archhead_addon/heap.py)."""
    import bpy
    import numpy as np

    from archhead_blender import api
    from archhead_blender.handlers import refresh_scene

    def settled_rss() -> float:
        refresh_scene(bpy.context.scene, bpy.context.evaluated_depsgraph_get())
        return resident_mb()

    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    heads, rss = [], {}
    for i in range(n):
        path = _sequence(folder, i, offset=not picture)
        if bpy.ops.archhead.import_sequence(filepath=str(path)) != {"FINISHED"}:
            raise SystemExit(f"could not import {path}")
        heads.append(bpy.data.objects[path.stem])
        bpy.context.view_layer.update()  # Blender's evaluated copies (of the shape keys too)
        rss.setdefault("one head", resident_mb())
    rss["heads"] = resident_mb()
    _load(heads[:1], checkpoint)  # one head with its avatar: what every further one adds to
    scene.frame_set(0)
    rss["one avatar"] = settled_rss()
    _load(heads[1:], checkpoint)  # one Load Avatar on every selected head
    scene.render.resolution_x, scene.render.resolution_y = size
    camera = scene.camera
    cam = np.array(camera.matrix_world)
    forward = -cam[:3, 2]  # Blender cameras look down their -Z
    right = cam[:3, 0]
    start = np.array(heads[0].parent.matrix_world)[:3, 3]
    d0 = np.linalg.norm(start - cam[:3, 3])
    for i, head in enumerate(heads[1:], 1):
        t = i / max(n - 1, 1)
        distance = NEAR * (FAR / NEAR) ** t  # evenly spread in log distance
        side = (-1) ** i * 0.25 * distance * ((i % 4) / 4)  # spread across the view
        head.parent.location = (start + forward * (distance - d0) + right * side).tolist()
    near, far = DRIVE_NEAR, DRIVE_FAR
    if picture:  # the camera stepped back: the nearest head whole in the frame, at LOD 0
        camera.location = (np.array(camera.location) - 1.2 * forward).tolist()
        near, far = near + 1.2, 4 * (near + 1.2)
    avatars = api.scene_avatars(scene)
    for obj in avatars:
        api.drive_lod_by_distance(obj, camera, near, far, "SCREEN")
    bpy.context.view_layer.update()
    extra = max(n - 1, 1)
    first = rss["one head"] + rss["one avatar"] - rss["heads"]
    per_head = (rss["heads"] - rss["one head"]) / extra
    return scene, avatars, (first, per_head, (settled_rss() - rss["one avatar"]) / extra)


def untrained_checkpoint(folder: Path, kind: str) -> Path:
    """An untrained avatar of the "demo" preset's size or of full size, written in `folder`
    by the backend (Blender's own Python has no torch)."""
    from archhead_blender import api

    checkpoint = folder / f"avatar_{kind}.npz"
    python = api.python_with_torch() or sys.executable
    command = [python, "-m", "archhead_addon.avatar.untrained", str(checkpoint)]
    subprocess.run(command + (["--preset", "demo"] if kind == "demo" else []), check=True)
    return checkpoint


def _load(heads, checkpoint: Path) -> None:
    import bpy

    if not heads:
        return
    bpy.ops.object.select_all(action="DESELECT")
    for head in heads:
        head.select_set(True)
    bpy.context.view_layer.objects.active = heads[0]
    if bpy.ops.archhead.load_avatar(filepath=str(checkpoint)) != {"FINISHED"}:
        raise SystemExit(f"could not load {checkpoint}")


def measure(
    n: int, kind: str, frames: int, size: tuple[int, int], picture=None, memory_total=None
) -> dict:
    import bpy

    from archhead_blender import api
    from archhead_blender.handlers import refresh_scene, resume, suspend
    from archhead_blender.preferences import get_preferences
    from archhead_blender.state import STATE

    api.enable_addon()
    if memory_total is not None:
        get_preferences(bpy.context).memory_total_mb = memory_total
    folder = api.scratch_folder("archhead_crowd_")
    if kind in ("demo", "full"):
        checkpoint = untrained_checkpoint(folder, kind)
    else:  # a trained checkpoint's path
        checkpoint = Path(kind).resolve()
    watch = api.Stopwatch()
    scene, avatars, (rss_first, rig_mb, avatar_mb) = _build(
        n, checkpoint, folder, size, bool(picture)
    )
    built_s = watch.seconds
    context = bpy.context
    sessions = [api.session(obj) for obj in avatars]
    # frames none of the avatars has shown yet (the build showed the current one)
    frame = iter(f for f in range(1, 40) if f != scene.frame_current)

    def frame_change() -> float:
        f = next(frame)
        start = time.perf_counter()
        scene.frame_set(f)
        return 1e3 * (time.perf_counter() - start)

    def gaussians() -> int:
        return sum(len(obj.data.vertices) for obj in avatars)

    def held_at(lod: float | None) -> float:
        for s in sessions:
            s.lod_override = lod
        return frame_change()

    # driven and LOD-0 frames in turn, so that neither gets the warmer caches or the quieter
    # stretch of a machine whose load drifts
    driven, lod0 = [], []
    for _ in range(frames):
        driven.append(held_at(None))
        driven_count = gaussians()
        lod0.append(held_at(0.0))
        lod0_count = gaussians()
    for s in sessions:
        s.lod_override = None
    driven_ms, lod0_ms = statistics.median(driven), statistics.median(lod0)
    # Blender's own part of a frame change (rigs, shape keys, drivers): the add-on paused
    suspend()
    try:
        blender_ms = statistics.median(frame_change() for _ in range(frames))
        # the same with each head's shape evaluated from its keys (Load Avatar pins its Basis)
        heads = [obj.archhead_avatar.head for obj in avatars]
        for head in heads:
            head.show_only_shape_key = False
        shapes_ms = statistics.median(frame_change() for _ in range(frames))
        for head in heads:
            head.show_only_shape_key = True
    finally:
        resume()
    model = decode_model(context, avatars)
    decode_frames = [next(frame) for _ in range(frames)]
    start = time.perf_counter()
    api.decode_frames(context, avatars, decode_frames)
    decode_ms = 1e3 * (time.perf_counter() - start) / (n * frames)
    # the handler on decoded frames: showing a cached frame (Blender's evaluation of the new
    # frame done with the add-on paused, then the handler alone), then with nothing to change
    cached = []
    for f in (decode_frames[1:] + decode_frames[:1]) * 3:  # each a change of frame
        suspend()
        try:
            scene.frame_set(f)
        finally:
            resume()
        depsgraph = context.evaluated_depsgraph_get()
        start = time.perf_counter()
        refresh_scene(scene, depsgraph)
        cached.append(1e3 * (time.perf_counter() - start) / n)
    cached_ms = statistics.median(cached)
    depsgraph = context.evaluated_depsgraph_get()
    idle = api.time_calls(lambda: refresh_scene(scene, depsgraph), 5).median_ms / n
    out = Path(api.scratch_folder("archhead_crowd_render_"))
    renders = {}
    for name, lod in (("driven", None), ("lod0", 0.0)):
        f = next(frame)
        start = time.perf_counter()
        api.render_frames(context, [f], out / name, lod=lod, exact=True)
        renders[name] = time.perf_counter() - start
    if picture:
        _picture(next((out / "driven").glob("*.png")), picture)
    # playback of the frames left, every avatar at LOD 0 (the most memory a frame takes):
    # what the memory caches keep, and the process's peak over the whole run
    for s in sessions:
        s.lod_override = 0.0
    played = 0
    for f in frame:
        scene.frame_set(f)
        played += 1
    cached_mb = sum(d.memory.nbytes for d in STATE.decoders.values()) / 2**20
    return {
        "heads": n,
        "avatar": kind,
        "build_s": round(built_s, 1),
        "rss_first_mb": round(rss_first),
        "rss_all_mb": round(rss_first + (n - 1) * (rig_mb + avatar_mb)),
        # what each further head adds: its import (mesh, shape keys, rig, animation), its avatar
        "mb_per_extra_head": round(rig_mb + avatar_mb, 1),
        "mb_per_extra_rig": round(rig_mb, 1),
        "mb_per_extra_avatar": round(avatar_mb, 1),
        "gaussians_driven": driven_count,
        "gaussians_lod0": lod0_count,
        "frame_change_ms_driven": round(driven_ms),
        "frame_change_ms_lod0": round(lod0_ms),
        "frame_change_ms_blender": round(blender_ms),
        "frame_change_ms_blender_shapes": round(shapes_ms),
        "decode_ms_per_head_frame": round(decode_ms, 1),
        "handler_ms_per_head_cached": round(cached_ms, 2),
        "handler_ms_per_head_idle": round(idle, 3),
        **model,
        "render_s_driven": round(renders["driven"], 2),
        "render_s_lod0": round(renders["lod0"], 2),
        "frames_played_lod0": played,
        "cached_mb_after_play": round(cached_mb),
        "rss_end_mb": round(resident_mb()),
        "rss_peak_mb": round(resident_mb("VmHWM")),
    }


def decode_model(context, avatars, repeats: int = 3) -> dict:
    """The heads' decodes alone, as a frame change runs them (`decode_requests`), at the
    scene's current frame: every head at LOD 1, 0.5 and 0, fitted as wall time = fixed + per
    texel x texels; then the heads at their driven levels and all at LOD 0, measured and as
    the fit gives them. What the fixed part (a head's FLAME pass, the Python between its
    products) costs the driven/LOD-0 ratio: with none the ratio would be the share of
    texels. After each driven measurement, the same levels with each head posed on its own
    decode thread (the path before a checkpoint's heads were posed together)."""
    import numpy as np

    from archhead_addon.avatar.runtime import decode_batch
    from archhead_blender import api
    from archhead_blender.avatar_session import FrameRequest, decode_requests

    depsgraph = context.evaluated_depsgraph_get()
    sessions = [api.session(obj) for obj in avatars]
    codes = [
        api.frame_codes(obj.archhead_avatar.head, depsgraph, s.joint_dirs)
        for obj, s in zip(avatars, sessions, strict=True)
    ]
    driven = [api.avatar_lod(obj, depsgraph) for obj in avatars]

    alone_ms = []

    def wall(lods, also_alone: bool = False) -> tuple[float, int]:
        triples = zip(sessions, codes, lods, strict=True)
        requests = [FrameRequest(s.shared, c, lod) for s, c, lod in triples]
        weights = [r.texels() for r in requests]
        alone = [lambda r=r: r.decoder.decode(r) for r in requests]  # each posing its head
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            decode_requests(requests)
            times.append(1e3 * (time.perf_counter() - start))
            if also_alone:
                start = time.perf_counter()
                decode_batch(alone, weights)
                alone_ms.append(1e3 * (time.perf_counter() - start))
        return statistics.median(times), sum(weights)

    uniform = [wall([lod] * len(avatars)) for lod in (1.0, 0.5, 0.0)]
    per_texel, fixed = np.polyfit([t for _, t in uniform], [ms for ms, _ in uniform], 1)
    driven_ms, driven_texels = wall(driven, also_alone=True)
    lod0_ms, lod0_texels = uniform[-1]
    return {
        "decode_ms_driven_posed_alone": round(statistics.median(alone_ms), 1),
        "decode_fixed_ms": round(float(fixed), 1),
        "decode_us_per_texel": round(1e3 * float(per_texel), 3),
        "decode_texels_driven": driven_texels,
        "decode_texels_lod0": lod0_texels,
        "decode_ms_driven": round(driven_ms, 1),
        "decode_ms_lod0": round(lod0_ms, 1),
        "decode_ratio_fit": round(
            float((fixed + per_texel * driven_texels) / (fixed + per_texel * lod0_texels)), 3
        ),
    }


def _picture(render: Path, picture: Path) -> None:
    """The render over white, its empty margins cut, in 256 colours (a small file for the
    README); copied as it is where Pillow is missing."""
    try:
        from PIL import Image
    except ImportError:
        shutil.copyfile(render, picture)
        return
    image = Image.open(render).convert("RGBA")
    white = Image.new("RGBA", image.size, (255, 255, 255, 255))
    flat = Image.alpha_composite(white, image).convert("RGB")
    box = image.getchannel("A").point(lambda a: 255 if a > 8 else 0).getbbox()
    if box:
        pad = 24
        box = (max(box[0] - pad, 0), max(box[1] - pad, 0), box[2] + pad, box[3] + pad)
        flat = flat.crop(box)
    flat.quantize(256, method=Image.Quantize.MEDIANCUT).save(picture, optimize=True)


def table(rows: list[dict]) -> str:
    lines = [
        "| N | avatar | Gaussians driven / LOD 0 "
        "| frame change ms driven / LOD 0 (ratio) / add-on paused (shapes evaluated) "
        "| Decode Frames ms per head-frame | handler ms per head: cached frame / idle "
        "| exact render s driven / LOD 0 | RSS first head / all "
        "| MB per extra head: all = imported head + avatar "
        "| after playing at LOD 0: frames cached / RSS / peak RSS, MB |",
        "|---:|---|---:|---|---:|---|---|---|---|---|",
    ]
    for r in rows:
        ratio = r["frame_change_ms_driven"] / max(r["frame_change_ms_lod0"], 1)
        lines.append(
            f"| {r['heads']} | {r['avatar']} | {r['gaussians_driven']:,} / "
            f"{r['gaussians_lod0']:,} | {r['frame_change_ms_driven']} / "
            f"{r['frame_change_ms_lod0']} ({ratio:.2f}x) / {r['frame_change_ms_blender']} "
            f"({r['frame_change_ms_blender_shapes']}) | "
            f"{r['decode_ms_per_head_frame']} | "
            f"{r['handler_ms_per_head_cached']} / {r['handler_ms_per_head_idle']} | "
            f"{r['render_s_driven']} / {r['render_s_lod0']} | {r['rss_first_mb']:,} / "
            f"{r['rss_all_mb']:,} MB | {r['mb_per_extra_head']} = {r['mb_per_extra_rig']} + "
            f"{r['mb_per_extra_avatar']} | {r['cached_mb_after_play']:,} / "
            f"{r['rss_end_mb']:,} / {r['rss_peak_mb']:,} |"
        )
    return "\n".join(lines)


def decode_table(rows: list[dict]) -> str:
    """The heads' decodes alone (`decode_model`): the driven/LOD-0 ratio measured, as the
    fit gives it, and as the share of texels (no fixed part at all)."""
    lines = [
        "| N | avatar | decodes alone, ms driven / LOD 0 (ratio) | fit: fixed ms + µs a texel "
        "(ratio) | texels driven / LOD 0 (share) | driven, each head posed alone, ms |",
        "|---:|---|---|---|---|---:|",
    ]
    for r in rows:
        driven, lod0 = r["decode_texels_driven"], r["decode_texels_lod0"]
        lines.append(
            f"| {r['heads']} | {r['avatar']} | {r['decode_ms_driven']} / {r['decode_ms_lod0']} "
            f"({r['decode_ms_driven'] / r['decode_ms_lod0']:.2f}x) | {r['decode_fixed_ms']} + "
            f"{r['decode_us_per_texel']} ({r['decode_ratio_fit']:.2f}x) | {driven:,} / "
            f"{lod0:,} ({driven / lod0:.2f}x) | {r['decode_ms_driven_posed_alone']} |"
        )
    return "\n".join(lines)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--heads", default="4,16,64")
    parser.add_argument("--avatars", default="demo,full")
    parser.add_argument("--size", default="1280x720")
    parser.add_argument("--frames", type=int, default=5)
    parser.add_argument("--json", type=Path)
    parser.add_argument("--picture", type=Path, help="write a driven render of a crowd here")
    parser.add_argument("--checkpoint", type=Path, help="the trained avatar of --picture")
    parser.add_argument("--picture-heads", type=int, default=16)
    parser.add_argument(
        "--memory-total",
        type=int,
        help="the preferences' memory for all avatars, MB (default: the preference's)",
    )
    parser.add_argument("--one", help=argparse.SUPPRESS)  # N,kind: measure in this process
    args = parser.parse_args(argv)
    size = tuple(int(v) for v in args.size.split("x"))
    if args.one:
        from archhead_addon.timing import restart_with_threads

        restart_with_threads(2)  # before bpy and numpy load their thread pools
        n, kind = args.one.split(",", 1)
        row = measure(int(n), kind, args.frames, size, args.picture, args.memory_total)
        print("ROW " + json.dumps(row), flush=True)
        return
    if (args.picture is None) != (args.checkpoint is None):
        parser.error("--picture and --checkpoint go together")

    def child(n: int, kind: str, picture=None) -> dict:
        command = [sys.executable, __file__, "--one", f"{n},{kind}"]
        command += ["--frames", str(args.frames), "--size", args.size]
        if args.memory_total is not None:
            command += ["--memory-total", str(args.memory_total)]
        command += ["--picture", str(picture.resolve())] if picture else []
        done = subprocess.run(command, capture_output=True, text=True)
        row = [line for line in done.stdout.splitlines() if line.startswith("ROW ")]
        if done.returncode or not row:
            print(done.stdout[-3000:], done.stderr[-3000:], file=sys.stderr)
            raise SystemExit(f"crowd of {n} {kind} avatars failed ({done.returncode})")
        return json.loads(row[0][4:])

    rows = []
    for kind in args.avatars.split(",") if args.avatars else ():
        for n in (int(v) for v in args.heads.split(",")):
            rows.append(child(n, kind))
            print(table(rows[-1:]).splitlines()[-1], flush=True)
    print(table(rows))
    print(decode_table(rows))
    if args.picture:
        child(args.picture_heads, str(args.checkpoint.resolve()), args.picture)
        print(f"crowd picture: {args.picture}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
