"""What a display that shows only the DC colour loses of a trained avatar: test PSNR with the
full colour (the exact splat render) and with the DC term alone, and the mean difference of
the two colours in 8-bit levels.

    python benchmarks/colour_display.py --avatar RUN/avatar.npz --data DIR [--frames 12]
        [--lods 0,0.5,1]

An avatar of SH degree 0 (the default since the colour's degree became a setting) shows the
same in both columns; a degree-3 avatar shows its loss. Blender's default display evaluates
the full colour towards the scene camera ("View-dependent colour" on), so it shows the first
column; the second is what it showed before (docs/training.md, "Colour").
"""

from __future__ import annotations

import argparse
from pathlib import Path


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--avatar", type=Path, required=True)
    parser.add_argument("--data", required=True)
    parser.add_argument("--frames", type=int, default=12)
    parser.add_argument("--lods", default="0,0.5,1")
    args = parser.parse_args(argv)

    import numpy as np
    import torch

    from archhead_addon.avatar.runtime import AvatarRuntime
    from archhead_addon.camera import affine_inverse
    from archhead_addon.evaluate.__main__ import run_config
    from archhead_addon.evaluate.metrics import psnr
    from archhead_addon.evaluate.render import driving_codes
    from archhead_addon.flame.model import load_model
    from archhead_addon.splat import kernel
    from archhead_addon.splat.colour_space import display_background, linear_to_srgb
    from archhead_addon.splat.sh import sh_to_rgb_numpy
    from archhead_addon.train.dataset import FrameDataset

    model = load_model()
    runtime = AvatarRuntime.load(args.avatar, model)
    run = run_config(args)  # the training run's config.json beside the avatar
    test = FrameDataset(
        args.data,
        run.get("resolution", 256),
        model,
        split="test",
        holdout=run.get("holdout", "last"),
    )
    picks = np.linspace(0, len(test) - 1, min(args.frames, len(test))).round().astype(int)
    degree, space = runtime.config.sh_degree, runtime.config.colour_space
    print(f"{args.avatar} (SH degree {degree}): {len(picks)} test frames of {args.data}\n")
    print("| l | PSNR full colour | PSNR DC only | colour difference, 8-bit levels |")
    print("|---:|---:|---:|---:|")
    for lod in (float(x) for x in args.lods.split(",")):
        scores, levels = [], []
        for i in picks:
            item = test[int(i)]
            codes = driving_codes(item["codes"])
            g = runtime.decode(lod, **codes)
            centre = affine_inverse(item["w2c"])[:3, 3]
            full = sh_to_rgb_numpy(degree, g.means - centre, g.sh)
            dc = sh_to_rgb_numpy(0, g.means - centre, g.sh[:, :1])
            shown = linear_to_srgb if space == "linear" else np.asarray
            levels.append(
                255 * np.abs(shown(np.clip(full, 0, 1)) - shown(np.clip(dc, 0, 1))).mean()
            )
            settings = kernel.RasterSettings(
                viewmat=np.asarray(item["w2c"], np.float64),
                K=np.asarray(item["K"], np.float64),
                width=test.size[1],
                height=test.size[0],
                background=tuple(map(float, display_background(test.background, space))),
            )
            truth = np.asarray(item["image"])
            row = []
            for colours in (full, dc):
                rgb = kernel.render(
                    g.means, g.quats, g.log_scales, g.opacity_logits, colours, settings
                ).rgb
                rgb = linear_to_srgb(rgb) if space == "linear" else rgb
                row.append(psnr(torch.as_tensor(rgb), torch.as_tensor(truth)))
            scores.append(row)
        full_db, dc_db = np.mean(scores, axis=0)
        print(f"| {lod:g} | {full_db:.2f} | {dc_db:.2f} | {np.mean(levels):.1f} |")


if __name__ == "__main__":
    main()
