"""The demo: everything on the built-in head, from a synthetic subject to a rendered clip.

    python -m archhead_blender.demo [--out DIR] [--checkpoint AVATAR.npz]  (the bpy module)
    python scripts/demo.py [...]                                            (the same)
    blender -b --python-exit-code 1 --python scripts/demo.py -- [--out DIR] [--checkpoint CKPT]
    python -m archhead_addon demo [...]                                     (the same)

An installed module (it runs from any folder); scripts/demo.py is a thin wrapper around
`main`, for Blender's --python and the checkout's commands.

Without --checkpoint it renders a small synthetic subject (Cycles) and trains a short avatar on
it with the project's training command (`python -m archhead_addon.train --config demo`, in a
separate process of an environment with torch). Then it imports the built-in talking-head
sequence, loads and decodes the avatar, renders a contact sheet of LOD 0 ... 1 from the tracked
camera, installs the camera-distance LOD driver on a dolly-in camera, renders the clip with the
exact splat kernel (PNG frames and a GIF) and saves the .blend. Prints where everything went
and how long each step took.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import bpy
import numpy as np

from archhead_addon.backend_process import PACKAGE_ROOT
from archhead_addon.threads import openmp_waiting_env

from . import api

SHEET_LODS = (0.0, 0.25, 0.5, 0.75, 1.0)
# White, the training background (train/dataset.py): an avatar learns its thin parts over it
BACKGROUND = (1.0, 1.0, 1.0)
NEAR, FAR = 0.5, 2.0  # camera distances (m) the driver maps to LOD 0 and LOD 1
DOLLY_FROM, DOLLY_TO = 2.4, 0.45  # the camera's distance at the first and last frame


def backend_python(fallback: str | None = None) -> str:
    """This Python when it has torch (the bpy module in the project's environment), else
    `fallback` (scripts/demo.py gives the checkout's .venv: Blender's own Python has none)."""
    python = api.python_with_torch() or fallback
    if not python:
        raise SystemExit("no Python with torch for the training: run the demo with one")
    return python


def train_avatar(data: Path, out: Path, config: str, python: str, waiting: dict) -> Path:
    """`waiting`: how training's OpenMP threads wait, chosen before the demo's own render
    loaded the cores (threads.openmp_waiting_env)."""
    if out.exists():  # an earlier demo's run: the demo trains anew (training would refuse)
        shutil.rmtree(out)
    command = api.train_command(python, data, out, config)
    print("demo: " + " ".join(command), flush=True)
    log = api.RunFolder(out.parent).log
    out.parent.mkdir(parents=True, exist_ok=True)
    # the archhead_addon beside this package, whatever that Python's site-packages hold (as
    # the add-on's backends run), from whatever folder the demo was started in
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(PACKAGE_ROOT), env.get("PYTHONPATH")]))
    env.update(waiting)
    with open(log, "w") as stream:
        status = subprocess.run(command, env=env, stdout=stream, stderr=subprocess.STDOUT)
    if status.returncode != 0:
        raise SystemExit(f"training failed (status {status.returncode}); see {log}")
    return api.RunFolder(out).avatar


def dolly_camera(scene, tracked, target: np.ndarray, frames: range):
    """A copy of the tracked camera moving along its view axis towards `target` (world),
    from DOLLY_FROM to DOLLY_TO metres over `frames`."""
    camera = bpy.data.objects.new("demo_dolly", tracked.data.copy())
    scene.collection.objects.link(camera)
    matrix = np.array(tracked.matrix_world)
    forward = -matrix[:3, 2] / np.linalg.norm(matrix[:3, 2])
    camera.matrix_world = tracked.matrix_world
    for frame, distance in ((frames.start, DOLLY_FROM), (frames.stop - 1, DOLLY_TO)):
        camera.location = target - distance * forward
        camera.keyframe_insert("location", frame=frame)
    scene.camera = camera
    return camera


def _pillow():
    """Pillow when this Python has it (the project's environment), else None: Blender's own
    Python lacks it, and the demo then writes unlabelled sheets and no GIF."""
    try:
        from PIL import Image, ImageDraw
    except ImportError:
        return None
    return Image, ImageDraw


def composite(path: Path) -> np.ndarray:
    """An RGBA PNG over BACKGROUND, (H,W,3) uint8."""
    rgba = api.read_image(path)
    rgb = rgba[..., :3] * rgba[..., 3:] + np.array(BACKGROUND) * (1 - rgba[..., 3:])
    return np.round(255 * rgb).astype(np.uint8)


def contact_sheet(context, runtime, frame: int, folder: Path, sheet: Path) -> list:
    """The avatar at SHEET_LODS from the scene camera at `frame`, side by side, labelled with
    the level of detail, the UV resolution S and the Gaussian count (with Pillow), cropped to
    the head; returns [(l, S, Gaussians)]."""
    tiles, alpha = [], []
    for lod in SHEET_LODS:
        path = api.render_frames(context, [frame], folder / f"lod_{lod:.2f}", lod=lod, exact=True)[
            0
        ]
        tiles.append(composite(path))
        alpha.append(api.read_image(path)[..., 3])
    rows, cols = np.nonzero(np.max(alpha, axis=0) > 8 / 255)
    pad = 6
    top, bottom = max(rows.min() - pad, 0), min(rows.max() + pad + 1, tiles[0].shape[0])
    left, right = max(cols.min() - pad, 0), min(cols.max() + pad + 1, tiles[0].shape[1])
    crops = [np.ascontiguousarray(t[top:bottom, left:right]) for t in tiles]
    for crop in crops[1:]:
        crop[:, 0] = 200  # a grey rule between tiles, since the background is white too
    levels = [
        (lod, runtime.resolution(lod), runtime.raster.table(runtime.resolution(lod)).count)
        for lod in SHEET_LODS
    ]
    pixels = np.concatenate(crops, axis=1)
    pillow = _pillow()
    if pillow is not None:
        Image, ImageDraw = pillow
        width, label = crops[0].shape[1], 26  # two lines of the default font
        out = Image.new("RGB", (pixels.shape[1], pixels.shape[0] + label), (255, 255, 255))
        out.paste(Image.fromarray(pixels), (0, label))
        draw = ImageDraw.Draw(out)
        for i, (lod, size, count) in enumerate(levels):
            draw.line([(i * width, 0), (i * width, out.height)], fill=(200, 200, 200))
            draw.text((i * width + 3, 1), f"LOD {lod:g}, S {size}\n{count:,} Gaussians", fill=0)
        pixels = np.asarray(out)
    else:
        print(
            "demo: contact sheet, left to right: "
            + "; ".join(
                f"LOD {lod:g}, S {size}, {count:,} Gaussians" for lod, size, count in levels
            )
        )
    sheet.parent.mkdir(parents=True, exist_ok=True)
    api.write_png(sheet, pixels.astype(np.float32) / 255, np.ones(pixels.shape[:2], np.float32))
    return levels


def write_gif(frames: list[Path], path: Path, fps: float) -> bool:
    """The clip as a looping GIF; False (nothing written) where Pillow is missing."""
    pillow = _pillow()
    if pillow is None:
        print("demo: no GIF (this Python has no Pillow); the clip's frames are PNGs")
        return False
    images = [pillow[0].fromarray(composite(p)) for p in frames]
    images[0].save(
        path, save_all=True, append_images=images[1:], duration=round(1000 / fps), loop=0
    )
    return True


def run(args, fallback_python: str | None = None) -> dict:
    """The whole demo; returns {what: path} and the step times."""
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    # chosen now: the subject's render would leave a load that training takes for other jobs'
    # and its threads would sleep (54 s of training instead of 41 on 2 quiet cores)
    waiting = openmp_waiting_env()
    steps = api.Steps("demo")
    with steps("built-in head"):
        model = api.load_model()
        print(
            f"demo: built-in head {model.model_id}: {model.n_verts:,} vertices, "
            f"{len(model.faces):,} faces, {model.n_shape} shape and {model.n_expr} "
            "expression components"
        )
    if args.checkpoint:
        checkpoint = Path(args.checkpoint).resolve()
    else:
        with steps("synthetic subject"):
            api.render_subject(
                out / "subject",
                args.subject_frames,
                args.subject_size,
                args.subject_samples,
                verbose=False,
            )
        with steps("training"):
            checkpoint = train_avatar(
                out / "subject",
                out / "train",
                args.train_config,
                backend_python(fallback_python),
                waiting,
            )

    api.enable_addon()
    bpy.ops.wm.read_homefile(use_empty=True)
    context, scene = bpy.context, bpy.context.scene
    with steps("import"):
        if args.sequence:
            sequence = Path(args.sequence).resolve()
        else:
            sequence = out / "demo.npz"
            api.write_canonical(api.demo_sequence(frames=args.frames), sequence)
        result = bpy.ops.archhead.import_sequence(filepath=str(sequence), frame_end=args.frames - 1)
        if result != {"FINISHED"}:
            raise SystemExit(f"import failed: {result}")
        render = scene.render  # the longer side to --size, the camera's aspect kept
        scale = args.size / max(render.resolution_x, render.resolution_y)
        render.resolution_x, render.resolution_y = (
            round(scale * render.resolution_x),
            round(scale * render.resolution_y),
        )
    head = bpy.data.objects[sequence.stem]
    with steps("load avatar"):
        context.view_layer.objects.active = head
        if bpy.ops.archhead.load_avatar(filepath=str(checkpoint)) != {"FINISHED"}:
            raise SystemExit(f"could not load {checkpoint}")
    avatar = bpy.data.objects[f"{head.name}_avatar"]
    runtime = api.session(avatar).runtime
    frames = range(scene.frame_start, scene.frame_end + 1)
    sheet = Path(args.sheet).resolve() if args.sheet else out / "contact_sheet.png"
    with steps("contact sheet"):
        levels = contact_sheet(context, runtime, frames.start, out / "sheet", sheet)

    target = np.array(head.matrix_world) @ np.append(
        np.mean([np.array(v) for v in head.bound_box], axis=0), 1
    )
    dolly = dolly_camera(scene, scene.camera, target[:3], frames)
    api.drive_lod_by_distance(avatar, dolly, NEAR, FAR)
    avatar.archhead_avatar.decode_frames = "ALL"
    with steps("decode"):
        decoded = api.decode_frames(context, avatar)
    with steps("render clip"):
        clip = api.render_frames(context, list(frames), out / "clip", exact=True)
        gif = out / "clip.gif" if write_gif(clip, out / "clip.gif", scene.render.fps) else None
    driven = {}
    for frame in (frames.start, frames.stop - 1):
        scene.frame_set(frame)
        driven[frame] = api.avatar_lod(avatar, context.evaluated_depsgraph_get())
    blend = out / "demo.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    summary = {
        "blend": str(blend),
        "contact_sheet": str(sheet),
        "clip": str(out / "clip"),
        "gif": str(gif) if gif else None,
        "checkpoint": str(checkpoint),
        "frames": len(clip),
        "decoded": decoded,
        "sheet_levels": levels,
        "driven_lod": {"first frame": driven[frames.start], "last frame": driven[frames.stop - 1]},
        "seconds": steps.seconds,
        "total_seconds": sum(steps.seconds.values()),
    }
    (out / "demo_summary.json").write_text(json.dumps(summary, indent=2))
    print(f"\ndemo done in {summary['total_seconds']:.0f} s")
    for name in ("blend", "contact_sheet", "clip", "gif", "checkpoint"):
        print(f"  {name:14s} {summary[name]}")
    print(f"  {'summary':14s} {out / 'demo_summary.json'}")
    return summary


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    parser.add_argument(
        "--checkpoint", help="a trained avatar of the built-in model (default: train a short one)"
    )
    parser.add_argument(
        "--sequence", help="tracked sequence to import (default: the built-in talking head)"
    )
    parser.add_argument("--frames", type=int, default=60, help="clip length")
    parser.add_argument("--size", type=int, default=256, help="clip and sheet size in pixels")
    parser.add_argument("--sheet", help="contact sheet path (default: OUT/contact_sheet.png)")
    parser.add_argument("--subject-frames", type=int, default=40)
    parser.add_argument("--subject-size", type=int, default=96)
    parser.add_argument("--subject-samples", type=int, default=8)
    parser.add_argument(
        "--train-config", default="demo", help="training config file or preset (default: demo)"
    )
    return parser.parse_args(argv)


def main(argv: list[str] | None = None, fallback_python: str | None = None) -> dict:
    """The demo with this command line's options (after `--` in Blender)."""
    return run(parse_args(api.script_args(sys.argv if argv is None else argv)), fallback_python)


if __name__ == "__main__":
    main()
