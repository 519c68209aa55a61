"""Where an avatar's squared error lies on a run's frames: inside the tracked head without
its neck, in the rest of the mask (hair beside and below the head, the neck), and outside
the mask (Gaussians drawn past the true silhouette, onto the background).

    python benchmarks/error_regions.py --avatar RUN/avatar.npz --data DIR [--lod 0]
        [--split test|train] [--resolution N] [--holdout last|interleaved] [--mask head|person]
        [--cut none|region]

Renders each frame as `evaluate` does (the run's resolution, holdout, masks and cut from
RUN/config.json unless given, read as `evaluate` reads them) and prints a Markdown table:
each region's share of the summed squared error and of the pixels. The codes are the
tracked ones (a run's refined tracking, `lr.codes`, is not read).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from archhead_addon.train.config import CUTS, HOLDOUTS, MASKS

REGIONS = ("the head without its neck", "the rest of the mask", "outside the mask")


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--avatar", type=Path, required=True, help="RUN/avatar.npz, config beside it")
    p.add_argument("--data", type=Path, required=True, help="the run's tracked folder")
    p.add_argument("--lod", type=float, default=0.0, help="the level scored")
    p.add_argument("--split", choices=("test", "train"), default="test")
    p.add_argument("--resolution", type=int, help="image size (default: the run's)")
    p.add_argument("--holdout", choices=HOLDOUTS, help="held-out frames (default: the run's)")
    p.add_argument("--mask", choices=MASKS, help="which masks cut the truth (default: the run's)")
    p.add_argument("--cut", choices=CUTS, help="what the renders are cut to (default: the run's)")
    return p.parse_args(argv)


def error_shares(args: argparse.Namespace) -> dict[str, tuple]:
    """{region: (share of the squared error, share of the pixels)} over the split's frames."""
    from archhead_addon.avatar.runtime import AvatarRuntime
    from archhead_addon.evaluate.__main__ import run_cut, run_holdout, run_mask, run_resolution
    from archhead_addon.evaluate.lods import cut_to_region
    from archhead_addon.evaluate.render import render_frame
    from archhead_addon.flame.model import load_model
    from archhead_addon.train.dataset import FrameDataset

    model = load_model(None)
    frames = FrameDataset(
        args.data,
        run_resolution(args),
        model,
        split=args.split,
        holdout=run_holdout(args),
        mask=run_mask(args),
    )
    runtime = AvatarRuntime.load(args.avatar, model)
    cut = run_cut(args) == "region"
    error, pixels = np.zeros(len(REGIONS)), np.zeros(len(REGIONS))
    for i in range(len(frames)):
        item = frames[i]
        rgb = render_frame(
            runtime, args.lod, item["codes"], item["K"], item["w2c"], frames.size, frames.background
        ).rgb
        if cut:
            rgb = cut_to_region(rgb, item["region"], frames.background)
        squared = ((np.clip(rgb, 0, 1) - item["image"]) ** 2).sum(axis=-1)
        head, mask = item["head"] > 0.5, item["mask"] > 0.5
        for k, region in enumerate((head, mask & ~head, ~mask & ~head)):
            error[k] += squared[region].sum()
            pixels[k] += region.sum()
    error /= max(error.sum(), 1e-30)
    pixels /= pixels.sum()
    return {name: (float(e), float(p)) for name, e, p in zip(REGIONS, error, pixels, strict=True)}


def main(argv=None) -> int:
    args = parse_args(argv)
    shares = error_shares(args)
    print(f"{args.avatar}, {args.split} frames, LOD {args.lod:g}", "", sep="\n")
    print(
        "| region | share of the squared error | share of the pixels |", "|---|---:|---:|", sep="\n"
    )
    for name, (error, pixels) in shares.items():
        print(f"| {name} | {100 * error:.0f} % | {100 * pixels:.0f} % |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
