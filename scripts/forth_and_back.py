"""A long test clip from a short one: its frames written forth, back, forth ... to N frames
(the tracker's frame budget is measured on such a clip: docs/tracking.md, "Long videos").

    .venv/bin/python scripts/forth_and_back.py ~/.cache/archhead/media/WolfgangLanger_Pexels.mp4 \\
        out/long/pexels_x6.mp4 --frames 1800
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("video", type=Path)
    p.add_argument("out", type=Path)
    p.add_argument("--frames", type=int, default=1800)
    args = p.parse_args(argv)
    source = cv2.VideoCapture(str(args.video))
    fps, frames = source.get(cv2.CAP_PROP_FPS), []
    while (read := source.read())[0]:
        frames.append(read[1])
    if not frames:
        raise SystemExit(f"{args.video}: no frame decoded")
    height, width = frames[0].shape[:2]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(args.out), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
    for n in range(args.frames):
        lap, at = divmod(n, len(frames))
        writer.write(frames[at] if lap % 2 == 0 else frames[-1 - at])
    writer.release()
    print(f"{args.out}: {args.frames} frames of {width}x{height} at {fps:.3f} fps")


if __name__ == "__main__":
    main()
