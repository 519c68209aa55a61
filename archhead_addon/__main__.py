"""The package's command line: `python -m archhead_addon COMMAND ...`.

Each command is a function in COMMANDS that adds its subparser and sets `run`, a function of
the parsed arguments returning the exit status. Commands import heavy modules (torch) inside
`run`, so `--help` and the light commands stay fast and torch-free. Bad input (InputError)
exits with status 2 and one `error:` line; input warnings print as `warning:` lines.
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys

from .io.cli import run_command
from .sequences import FORMAT_NAMES, read_sequence, write_canonical
from .track.cli import add_subject, add_track
from .video_avatar import add_avatar


def _add_convert(commands) -> None:
    p = commands.add_parser(
        "convert",
        help="convert a tracked sequence to ArchHead's .npz",
        description="Read a tracked FLAME sequence and write ArchHead's "
        "canonical .npz (docs/formats.md).",
    )
    p.add_argument("input", help="sequence file or folder")
    p.add_argument("output", help="canonical .npz to write (replaced atomically)")
    p.add_argument("--format", choices=FORMAT_NAMES, help="input format (default: detected)")
    p.add_argument(
        "--fps",
        type=float,
        help="frame rate, for formats that store none (or to override the stored one)",
    )
    p.add_argument(
        "--camera",
        type=int,
        help="camera_index of a multi-view VHAP / GaussianAvatars folder (default: the lowest)",
    )
    p.set_defaults(run=_convert)


def _convert(args) -> int:
    seq = read_sequence(args.input, args.format, fps=args.fps, camera=args.camera)
    write_canonical(seq, args.output)
    camera = f"{seq.image_size[1]}x{seq.image_size[0]}" if seq.has_camera else "none"
    print(
        f"{args.output}: {len(seq)} frames, {seq.fps:g} fps, from {seq.format}, shape "
        f"{seq.shape.shape[1]}, expr {seq.expr.shape[1]}, camera {camera}"
    )
    return 0


DEMO_MODULE = "archhead_blender.demo"


def _add_demo(commands) -> None:
    p = commands.add_parser(
        "demo",
        help="the whole pipeline on the built-in head (bpy module)",
        add_help=False,  # --help is the demo's own, with every option it takes
    )
    p.set_defaults(run=_demo, passes_on=True)  # every other argument goes to the demo


def _demo(args) -> int:
    # A child process: bpy loads Blender's whole runtime, which this light CLI stays without.
    # The demo is an installed module of the Blender side, so it runs from any folder.
    return subprocess.run([sys.executable, "-m", DEMO_MODULE, *args.options]).returncode


COMMANDS = (_add_convert, _add_demo, add_track, add_subject, add_avatar)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m archhead_addon", description="ArchHead command line tools."
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add in COMMANDS:
        add(commands)
    args, rest = parser.parse_known_args(argv)
    if rest and not getattr(args, "passes_on", False):
        parser.error(f"unrecognized arguments: {' '.join(rest)}")
    args.options = rest
    # Ctrl-C and Blender's Cancel (SIGINT) stop the command even when it was started from a
    # process that ignores SIGINT (a shell's background job, and Blender started as one):
    # an ignored SIGINT is inherited, and a cancelled tracking would run on to the end.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    return run_command(lambda: args.run(args))


if __name__ == "__main__":
    sys.exit(main())
