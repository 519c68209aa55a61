"""What each of a training step's run-long savings is worth, in one process.

    python benchmarks/step_changes.py --data out/real_hn [--config cpu] [--blocks 4]
                                      [--steps 40] [--warm 150]

`training_profile.py` times single steps back to back, which cannot see what only shows over
many steps. This runs blocks of real `Trainer.train_step`s (from an eighth into stage 1 and
a sixth into stage 2), each block once per variant, the variants in turn, every
variant on the same steps (frames and levels), and prints milliseconds per step and the
median over blocks of each variant's speed-up against "before":

- "before": all three off, as the step was: the per-resolution tables bounded by count (the
  32 most recent; stage 2 draws S from every size between s_min and s_max, so most of its
  steps built a table, a UV raster included), FLAME posed from each frame's codes on every
  render, and Adam's loop over its tensors;
- "tables": only the tables kept by bytes (`avatar.level_cache`, every sampled S stays);
- "pose": only each frame's FLAME pose kept (`Trainer._posed`);
- "adam": only fused Adam;
- "after": all three (the trainer as it is).

The avatar trains through the blocks (an untrained one from the config; each stage's first
`--warm` steps untimed fill the tables), so the variants share its state as it goes.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from collections import OrderedDict
from pathlib import Path

from archhead_addon.heap import keep_freed_memory
from archhead_addon.threads import choose_openmp_waiting, limit_thread_environment

OLD_TABLES = 32  # the count bound the model's tables had
VARIANTS = ("before", "tables", "pose", "adam", "after")
ON = {"before": (), "tables": ("tables",), "pose": ("pose",), "adam": ("adam",)}
ON["after"] = ("tables", "pose", "adam")


class CountBoundTables:
    """The model's per-resolution tables as they were kept: the `OLD_TABLES` most recent."""

    def __init__(self, build):
        self.build, self.tables = build, OrderedDict()

    def __call__(self, size: int, kind):
        key = (int(size), kind)
        if key in self.tables:
            self.tables.move_to_end(key)
        else:
            self.tables[key] = self.build(*key)
            if len(self.tables) > OLD_TABLES:
                self.tables.popitem(last=False)
        return self.tables[key]


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, required=True, help="a tracked subject folder")
    p.add_argument("--config", default="cpu", help="training config file or preset")
    p.add_argument("--blocks", type=int, default=4, help="blocks per variant and stage")
    p.add_argument("--steps", type=int, default=40, help="steps per block")
    p.add_argument("--warm", type=int, default=150, help="untimed steps before each stage")
    args = p.parse_args(argv)
    keep_freed_memory()  # as the training command does
    choose_openmp_waiting()
    limit_thread_environment()

    import torch

    from archhead_addon.train.__main__ import parse_args, setup
    from archhead_addon.train.progress import Progress

    with tempfile.TemporaryDirectory() as tmp:  # nothing is saved: the steps are called alone
        train_args = ["--data", str(args.data), "--out", str(Path(tmp) / "run")]
        trainer = setup(parse_args([*train_args, "--config", args.config]), Progress(None))
    avatar = trainer.avatar
    kept_tables, old_tables = avatar.level_cache, CountBoundTables(avatar._build_level)
    fused = trainer.optimizer
    plain = torch.optim.Adam(fused.param_groups)
    plain.load_state_dict(fused.state_dict())
    for group in plain.param_groups:  # the groups, and the state, bring fused=True with them
        group["fused"] = None
    assert all(g["fused"] for g in fused.param_groups)
    kept_pose = trainer._posed

    def switch(variant: str) -> None:
        on = ON[variant]
        avatar.level_cache = kept_tables if "tables" in on else old_tables
        trainer._posed = kept_pose if "pose" in on else (lambda frame: None)
        trainer.optimizer = fused if "adam" in on else plain

    print(
        f"# Step changes: {args.data} ({len(trainer.frames)} training frames), config "
        f"{args.config}, {torch.get_num_threads()} threads, {args.blocks} blocks of "
        f"{args.steps} steps per variant and stage; load average {os.getloadavg()[0]:.2f}\n"
    )
    print("| stage | variant | ms per step, each block | median | speed-up over before |")
    print("|---|---|---|---:|---:|")
    cfg = trainer.config
    for stage, first in ((1, cfg.stage1_steps // 8), (2, cfg.stage1_steps + cfg.stage2_steps // 6)):
        switch("after")
        trainer.step = first
        for _ in range(args.warm):
            trainer.train_step()
        first += args.warm
        ms = {v: [] for v in VARIANTS}
        for block in range(args.blocks):
            for variant in VARIANTS:
                switch(variant)
                trainer.step = first + block * args.steps
                start = time.perf_counter()
                for _ in range(args.steps):
                    trainer.train_step()
                ms[variant].append(1e3 * (time.perf_counter() - start) / args.steps)
        for variant in VARIANTS:
            ratio = statistics.median(b / x for b, x in zip(ms["before"], ms[variant], strict=True))
            blocks = " / ".join(f"{x:.1f}" for x in ms[variant])
            print(
                f"| {stage} | {variant} | {blocks} | {statistics.median(ms[variant]):.1f} "
                f"| {ratio:.3f}x |"
            )
    print(f"\nload average at the end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
