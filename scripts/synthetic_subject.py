"""Render the synthetic subject: the built-in head (with teeth) along a known trajectory.

    .venv/bin/python scripts/synthetic_subject.py --out DIR [--frames 300] [--size 256]
                                                  [--samples 16] [--seed 0] [--fps 25]
    blender -b --python-exit-code 1 --python scripts/synthetic_subject.py -- --out DIR ...

What it writes: archhead_blender/synthetic_subject.py. Never imports torch.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from archhead_blender import api


def main(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--size", type=int, default=256, help="square image size in pixels")
    parser.add_argument(
        "--samples",
        type=int,
        default=api.SUBJECT_SAMPLES,
        help="Cycles samples per pixel (denoised above 4)",
    )
    parser.add_argument("--seed", type=int, default=0, help="trajectory seed")
    parser.add_argument("--fps", type=float, default=25.0)
    parser.add_argument("--threads", type=int, default=0, help="render threads (0: all cores)")
    args = parser.parse_args(argv)
    if args.frames < 1 or args.size < 8 or args.samples < 1:
        parser.error("--frames and --samples must be positive and --size at least 8")
    api.render_subject(
        args.out, args.frames, args.size, args.samples, args.seed, args.fps, args.threads
    )


if __name__ == "__main__":
    main(api.script_args(sys.argv))
