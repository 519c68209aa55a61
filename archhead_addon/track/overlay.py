"""Overlay images: the tracked head drawn over its frames, for people to judge a tracking."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..flame.lbs import forward
from ..flame.model import FlameModel
from ..sequences import read_sequence
from ..train.dataset import FRAMES_DIR, TRACKING_FILE, numbered_images
from ..train.images import read_image
from .render import render_mesh


def overlay(model: FlameModel, frame: np.ndarray, verts, K, w2c, alpha: float = 0.45):
    """The frame (H,W,3) float with the shaded mesh blended over it where it covers."""
    shaded, hit, _, _ = render_mesh(model, verts, K, w2c, frame.shape[:2])
    out = frame.copy()
    out[hit] = (1 - alpha) * frame[hit] + alpha * shaded[hit]
    return out


def overlay_sheet(data, model: FlameModel, picks: int = 6, width: int = 256) -> np.ndarray:
    """A row of `picks` frames spread over the clip: frame above, overlay below; uint8."""
    data = Path(data)
    seq = read_sequence(data / TRACKING_FILE).fit_to_model(model)
    files = numbered_images(data / FRAMES_DIR)
    chosen = np.linspace(0, len(files) - 1, picks).round().astype(int)
    columns = []
    for i in chosen:
        frame = read_image(files[i][1])[0][..., :3]
        verts = forward(
            model,
            shape=seq.shape[i],
            expr=seq.expr[i],
            jaw=seq.jaw[i],
            neck=seq.neck[i],
            eyes=seq.eyes[i],
            rotation=seq.rotation[i],
            translation=seq.translation[i],
            static_offset=seq.static_offset,
        )[0]
        columns.append(
            np.concatenate([frame, overlay(model, frame, verts, seq.K[i], seq.w2c[i])], axis=0)
        )
    from ..train.images import resize

    sheet = np.concatenate([resize(c, (2 * width, width)) for c in columns], axis=1)
    return np.round(np.clip(sheet, 0, 1) * 255).astype(np.uint8)


def main(argv=None) -> int:
    import argparse

    from ..flame.model import load_model
    from ..io.atomic import write_bytes_atomic
    from ..synthetic.png import encode_png

    parser = argparse.ArgumentParser(
        prog="python -m archhead_addon.track.overlay",
        description="Frames over tracked-mesh overlays, as a PNG.",
    )
    parser.add_argument("--data", required=True, help="a tracked training folder")
    parser.add_argument("--out", required=True, help="PNG to write")
    parser.add_argument("--picks", type=int, default=6)
    parser.add_argument("--flame", help="the FLAME model it was tracked with")
    args = parser.parse_args(argv)
    sheet = overlay_sheet(args.data, load_model(args.flame), args.picks)
    write_bytes_atomic(args.out, encode_png(sheet))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
