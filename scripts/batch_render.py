"""Render frames of a .blend with ArchHead avatars, without the UI.

    blender -b scene.blend --python-exit-code 1 --python scripts/batch_render.py -- \
        --frames 1-20 --out DIR
    python scripts/batch_render.py scene.blend --frames 1-20 --out DIR     (the bpy module)

Options: --lod L fixes every avatar's level of detail (else its keys or driver decide);
--exact renders the Gaussians with the splat kernel instead of the scene's engine (RGBA PNG);
--cache-dir DIR keeps decoded frames there (share it between render-farm machines);
--decode-only fills that cache without rendering; --engine and --samples override the scene.
Frames are written as DIR/frame_####.<ext>. Each frame range is an independent unit of work,
so a farm manager can split a job by ranges (docs/blender_avatar.md has the recipe).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import bpy

from archhead_blender import api


def main(argv: list[str]) -> list[Path]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "blend",
        nargs="?",
        help=".blend to open (the bpy module; `blender -b FILE` has opened it already)",
    )
    parser.add_argument("--frames", required=True, help="e.g. 1-20, 1-20:5 or 3,7,9")
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--lod", type=float, default=None)
    parser.add_argument("--exact", action="store_true")
    parser.add_argument("--cache-dir", default=None)
    parser.add_argument("--decode-only", action="store_true")
    parser.add_argument(
        "--engine",
        choices=("CYCLES", "BLENDER_EEVEE", "BLENDER_EEVEE_NEXT", "BLENDER_WORKBENCH"),
        help="either EEVEE name means this Blender's EEVEE (4.2-4.4 call it BLENDER_EEVEE_NEXT)",
    )
    parser.add_argument("--samples", type=int, default=None)
    args = parser.parse_args(argv)
    if args.decode_only and not args.cache_dir:
        parser.error("--decode-only needs --cache-dir")

    api.enable_addon()
    if args.blend:
        bpy.ops.wm.open_mainfile(filepath=str(Path(args.blend).resolve()))
    scene = bpy.context.scene
    if not api.scene_avatars(scene):
        raise SystemExit("the scene has no ArchHead avatar")
    if args.cache_dir:
        for obj in api.scene_avatars(scene):
            obj.archhead_avatar.cache_dir = str(Path(args.cache_dir).resolve())
            obj.archhead_avatar.disk_cache = True
    if args.engine:
        eevee = args.engine.startswith("BLENDER_EEVEE")
        scene.render.engine = api.eevee_engine() if eevee else args.engine
    if args.samples is not None:
        if scene.render.engine == "CYCLES":
            scene.cycles.samples = args.samples
        else:
            scene.eevee.taa_render_samples = args.samples
    written = api.render_frames(
        bpy.context,
        api.parse_frames(args.frames),
        args.out,
        lod=args.lod,
        exact=args.exact,
        decode_only=args.decode_only,
    )
    for path in written:
        print(f"wrote {path}")
    return written


if __name__ == "__main__":
    main(api.script_args(sys.argv))
