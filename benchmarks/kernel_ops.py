"""What the splat kernel's one-pass operations are worth to a training step.

    python benchmarks/kernel_ops.py --data out/real_hn --avatar RUN/avatar.npz
                                    [--config cpu] [--steps 90] [--threads 2]

Three parts of a training step run in the splat kernel's library on a CPU, each in one pass
(or two) where torch takes a dozen operations each way: the feature field's bicubic
resample (`kernel.resample_forward`, by four taps an output where the torch form multiplies
dense matrices), the render's sRGB encoding and the loss's two Huber terms (`srgb_encode`,
`image_huber`, which write their gradients with their values). This times, in one process:

- each alone, forward and backward, torch against the kernel;
- real `Trainer.train_step`s of both stages (from the trained avatar `--avatar`), every step
  taken four ways: "before" (all three in torch), "image" (the encoding and the terms by
  the kernel), "resample" (the resample by the kernel) and "after" (all three, as training
  runs). The order of the four turns with each step: the first to run a step finds its
  frame and level tables colder, which alone moves a step by as much as these changes.

Prints each variant's median milliseconds a step and the median of its per-step speed-ups
over "before".
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from functools import partial
from pathlib import Path

from training_profile import make_trainer, training_setup


def _us(fn, repeats: int = 100) -> float:
    for _ in range(5):
        fn()
    start = time.perf_counter()
    for _ in range(repeats):
        fn()
    return 1e6 * (time.perf_counter() - start) / repeats


def operations_alone(size: int, avatar) -> None:
    import torch

    from archhead_addon.avatar.resample import texel_features, texel_features_torch
    from archhead_addon.splat.colour_space import linear_to_srgb_ops, linear_to_srgb_torch
    from archhead_addon.train.config import LossWeights
    from archhead_addon.train.losses import TrainingLoss, huber, parts_huber

    gen = torch.Generator().manual_seed(0)
    linear = torch.rand(size, size, 3, generator=gen).requires_grad_(True)
    target = torch.rand(size, size, 3, generator=gen)
    parts = torch.rand(size, size, generator=gen)
    grad = torch.rand(size, size, 3, generator=gen)
    loss = TrainingLoss(LossWeights())

    def terms(fn):
        rgb, part = fn(linear)
        (rgb + 20 * part).backward()

    rows = [
        ("sRGB encoding", lambda: linear_to_srgb_ops(linear).backward(grad),
         lambda: linear_to_srgb_torch(linear).backward(grad)),
        ("two Huber terms", lambda: terms(lambda p: (huber(p, target, 1.0),
                                                     parts_huber(p, target, parts, 1.0))),
         lambda: terms(lambda p: loss.image_terms(p, target, parts))),
    ]  # fmt: skip
    cfg = avatar.config
    for lod in (0.0, 0.5, 1.0):
        lv = avatar.level(round(cfg.s_max - lod * (cfg.s_max - cfg.s_min)))

        def field(fn, lv=lv):
            out = fn(avatar.features, lv["resample"], lv["texel"])
            out.backward(torch.ones_like(out))

        name = f"resample, {len(lv['texel']):,} texels (LOD {lod:g})"
        rows.append((name, partial(field, texel_features_torch), partial(field, texel_features)))
    print(f"Each alone, forward and backward (images {size}x{size}x3), microseconds:\n")
    print("| operation | torch | kernel | speed-up |")
    print("|---|---:|---:|---:|")
    for name, ops, kernel in rows:
        a, b = _us(ops), _us(kernel)
        print(f"| {name} | {a:,.0f} | {b:,.0f} | {a / b:.2f}x |")
    avatar.zero_grad(set_to_none=True)
    print()


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, required=True, help="a tracked subject folder")
    p.add_argument("--avatar", type=Path, required=True, help="a trained avatar.npz")
    p.add_argument("--config", default="cpu", help="training config file or preset")
    p.add_argument("--steps", type=int, default=90, help="steps per stage, each taken 4 ways")
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)
    config, dataset, frames = training_setup(args)

    from archhead_addon.avatar import model
    from archhead_addon.avatar.resample import texel_features_torch
    from archhead_addon.splat.colour_space import linear_to_srgb_ops
    from archhead_addon.train import loop, losses

    print(
        f"# The kernel's operations in a training step: {args.data}, config {args.config}, "
        f"{args.threads} threads; load average {os.getloadavg()[0]:.2f}\n"
    )
    trainer = make_trainer(config, dataset, frames, args.avatar, Path(tempfile.mkdtemp()))
    operations_alone(config.resolution, trainer.avatar)

    def torch_terms(self, pred, target, parts):
        delta = self.weights.huber_delta
        return losses.huber(pred, target, delta), losses.parts_huber(pred, target, parts, delta)

    kernel = (loop.linear_to_srgb_torch, losses.TrainingLoss.image_terms, model.texel_features)
    image_torch = (linear_to_srgb_ops, torch_terms)

    def patch(parts) -> None:
        loop.linear_to_srgb_torch, losses.TrainingLoss.image_terms, model.texel_features = parts

    variants = {
        "before": (*image_torch, texel_features_torch),
        "image": (*kernel[:2], texel_features_torch),
        "resample": (*image_torch, kernel[2]),
        "after": kernel,
    }
    seconds = {name: {1: [], 2: []} for name in variants}
    try:
        for stage, first in ((1, config.stage1_steps // 8), (2, config.stage1_steps + 100)):
            for k in range(args.steps):
                names = list(variants)
                turn = k % len(names)
                for name in names[turn:] + names[:turn]:
                    patch(variants[name])
                    trainer.step = first + k
                    start = time.perf_counter()
                    trainer.train_step()
                    seconds[name][stage].append(time.perf_counter() - start)
    finally:
        patch(kernel)
    print(f"Training steps, {args.steps} per stage, each taken four ways in turn:\n")
    print("| stage | variant | ms a step (median) | speed-up over before (median per step) |")
    print("|---|---|---:|---:|")
    for stage in (1, 2):
        before = seconds["before"][stage]
        for name in variants:
            times = seconds[name][stage]
            ratio = statistics.median(b / t for b, t in zip(before, times, strict=True))
            print(f"| {stage} | {name} | {1e3 * statistics.median(times):.1f} | {ratio:.3f}x |")
    print(f"\nload average at the end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
