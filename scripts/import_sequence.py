"""Import a tracked sequence and save a .blend, without the UI.

    blender -b --python-exit-code 1 --python scripts/import_sequence.py -- SEQUENCE OUT.blend ...
    python scripts/import_sequence.py SEQUENCE OUT.blend ...      (the `bpy` module)

SEQUENCE `demo` imports the built-in talking-head trajectory on the built-in model.

The add-on is enabled first: the installed extension when there is one, else this checkout
through a temporary extension repository (Blender's own add-on loading either way).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import bpy

from archhead_blender import api


def _write_demo_sequence() -> str:
    path = api.scratch_folder("archhead_demo_") / "demo.npz"
    api.write_canonical(api.demo_sequence(), path)
    return str(path)


def main(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sequence")
    parser.add_argument("out", help=".blend file to write")
    parser.add_argument("--first", type=int, default=0)
    parser.add_argument("--last", type=int, default=-1)
    parser.add_argument("--stride", type=int, default=1)
    parser.add_argument("--fps", type=float, default=0.0)
    parser.add_argument("--expressions", type=int, default=100)
    parser.add_argument("--no-camera", action="store_true")
    parser.add_argument(
        "--correctives", choices=("DRIVERS", "KEYFRAMES", "NONE"), default="DRIVERS"
    )
    args = parser.parse_args(argv)
    api.enable_addon()
    if args.sequence == "demo":
        args.sequence = _write_demo_sequence()
    result = bpy.ops.archhead.import_sequence(
        filepath=str(Path(args.sequence).resolve()),
        frame_start=args.first,
        frame_end=args.last,
        stride=args.stride,
        target_fps=args.fps,
        n_expr=args.expressions,
        use_camera=not args.no_camera,
        pose_correctives=args.correctives,
    )
    if result != {"FINISHED"}:
        raise SystemExit(f"import failed: {result}")
    bpy.ops.wm.save_as_mainfile(filepath=str(Path(args.out).resolve()))
    print(f"saved {args.out}")


if __name__ == "__main__":
    main(api.script_args(sys.argv))
