"""Training-step time of perceptual-term schedules, back to back in one process.

    python benchmarks/lpips_schedule.py [--data DIR] [--config cpu|FILE]
                                        [--avatar RUN/avatar.npz] [--steps 16] [--threads 2]
                                        [--variant NAME=JSON ...]

Each variant is the config with some keys changed (default: ST-LPIPS on one stage-2 render
per step, `lpips_levels` "one"; and on every 8th step, `lpips_every` 8). Every
variant times the same real `Trainer.train_step`s, stage 1 and then stage 2 from step
`stage1_steps`, from the same avatar (each step's update undone: `training_profile.Profiler`),
the variants in turn step by step, so that the machine's load falls on all of them alike.
The table gives milliseconds per step as training takes them: the medians of the steps with
ST-LPIPS and of those without, weighted by their shares (`training_profile._expected`); the
ratio is of these figures: the config as it is over the variant.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
from dataclasses import replace
from pathlib import Path

from training_profile import DEFAULT_DATA, Profiler, _expected, make_trainer, training_setup

DEFAULT_VARIANTS = {
    "one stage-2 render": {"lpips_levels": "one"},
    "every 8th step": {"lpips_every": 8},
}


def _variant(text: str) -> tuple[str, dict]:
    name, _, changes = text.partition("=")
    return name, json.loads(changes)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, default=DEFAULT_DATA, help="subject folder")
    p.add_argument("--config", default="cpu", help="training config file or preset")
    p.add_argument("--avatar", type=Path, help="a trained avatar.npz every step starts from")
    p.add_argument("--steps", type=int, default=16, help="steps per stage and variant")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument(
        "--variant",
        type=_variant,
        action="append",
        help='NAME={"key": value, ...}: config changes to time (repeatable)',
    )
    args = p.parse_args(argv)
    config, dataset, frames = training_setup(args)

    import torch

    variants = {"as configured": {}, **dict(args.variant or DEFAULT_VARIANTS)}
    profilers = {}
    with tempfile.TemporaryDirectory() as tmp:  # nothing is saved: the steps are called alone
        for name, changes in variants.items():
            cfg = replace(config, **changes)
            profilers[name] = Profiler(make_trainer(cfg, dataset, frames, args.avatar, tmp))
    print(
        f"# Perceptual-term schedules: {args.data} ({len(frames)} training frames), config "
        f"{args.config}, avatar {args.avatar or 'untrained'}, {torch.get_num_threads()} "
        f"threads, {args.steps} steps per stage and variant\n"
    )
    configs = {name: profiler.trainer.config for name, profiler in profilers.items()}
    cycle = math.lcm(*(c.lpips_every * c.lods_per_step for c in configs.values()))
    steps = -(-args.steps // cycle) * cycle  # whole cycles of every schedule
    print("| stage | variant | ms per step | as configured / variant |\n|---|---|---:|---:|")
    for stage, first in ((1, 0), (2, config.stage1_steps)):
        times = {name: [] for name in variants}
        for i in range(-1, steps):  # i = -1: an untimed warm-up of each variant
            for name, profiler in profilers.items():
                ms = profiler.step(first + max(i, 0))
                if i >= 0:
                    times[name].append(ms)
        expected = {
            name: _expected(t, [_uses_lpips(configs[name], first + i) for i in range(steps)])
            for name, t in times.items()
        }
        for name, ms in expected.items():
            print(f"| {stage} | {name} | {ms:.1f} | {expected['as configured'] / ms:.2f}x |")


def _uses_lpips(config, step: int) -> bool:
    return config.loss.lpips > 0 and step % config.lpips_every == 0


if __name__ == "__main__":
    main()
