"""What keeping freed memory in the process is worth to training (`heap.keep_freed_memory`,
which the `train` and `track` commands call first).

    python benchmarks/freed_memory.py --data DATA [--run RUN] [--pairs 3] [--blocks 6]
                                      [--steps 20]

Each pair runs two fresh processes one after the other, without and with
`keep_freed_memory()` (malloc's settings hold for a whole process, so the two cannot take
turns in one), in alternating order from pair to pair. Each process takes the same real
`Trainer.train_step`s: a warm-up, then `--blocks` blocks of `--steps` steps from the middle
of stage 1 and from a sixth into stage 2. RUN: a run folder to start from (its avatar and
config, copied; a finished run's Gaussians cost what a run's do), else a new run of the
`cpu` preset. Blocks of one process differ (each step draws its own frame and levels), so
the ratios compare the same blocks: per stage and pair, the sum of the blocks without over
the sum with. Also prints page faults per step (`ru_minflt`) and each process's peak RSS.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def child(args) -> None:
    """One process's blocks, printed as one JSON line."""
    from archhead_addon.heap import keep_freed_memory, resident_mb
    from archhead_addon.threads import choose_openmp_waiting, limit_thread_environment

    kept = keep_freed_memory() if args.keep else False
    choose_openmp_waiting()
    limit_thread_environment()
    import resource

    from archhead_addon.train.__main__ import parse_args, setup
    from archhead_addon.train.progress import Progress

    tmp = Path(tempfile.mkdtemp())
    try:
        out = tmp / "run"
        if args.run:
            shutil.copytree(args.run, out)
            train_args = ["--data", str(args.data), "--out", str(out), "--resume"]
        else:
            train_args = ["--data", str(args.data), "--out", str(out), "--config", "cpu"]
        trainer = setup(parse_args(train_args), Progress(None))
        cfg = trainer.config
        result = {"kept": kept}
        starts = (cfg.stage1_steps // 2, cfg.stage1_steps + cfg.stage2_steps // 6)
        for stage, first in enumerate(starts, 1):
            trainer.step = first
            for _ in range(args.warm):
                trainer.train_step()
            faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
            blocks = []
            for _ in range(args.blocks):
                start = time.perf_counter()
                for _ in range(args.steps):
                    trainer.train_step()
                blocks.append(1e3 * (time.perf_counter() - start) / args.steps)
            faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults
            result[f"stage{stage}"] = {
                "blocks": blocks,
                "faults": faults / (args.blocks * args.steps),
            }
        result["peak_mb"] = resident_mb("VmHWM")
        print("RESULT " + json.dumps(result), flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def run_child(args, keep: bool) -> dict:
    command = [sys.executable, __file__, "--child", "--data", str(args.data),
               "--blocks", str(args.blocks), "--steps", str(args.steps),
               "--warm", str(args.warm)]  # fmt: skip
    command += ["--run", str(args.run)] if args.run else []
    done = subprocess.run(command + (["--keep"] if keep else []), capture_output=True, text=True)
    if done.returncode:
        sys.exit(done.stdout + done.stderr)
    line = next(x for x in done.stdout.splitlines() if x.startswith("RESULT "))
    return json.loads(line[len("RESULT ") :])


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, required=True, help="a tracked subject folder")
    p.add_argument("--run", type=Path, help="a run folder to start from (copied)")
    p.add_argument("--pairs", type=int, default=3)
    p.add_argument("--blocks", type=int, default=6, help="blocks per stage")
    p.add_argument("--steps", type=int, default=20, help="steps per block")
    p.add_argument("--warm", type=int, default=20, help="untimed steps before each stage")
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--keep", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child:
        return child(args)
    print(
        f"# Freed memory kept: {args.data}"
        + (f" from {args.run}" if args.run else "")
        + f", {args.pairs} pairs of processes, {args.blocks} blocks of {args.steps} steps "
        f"per stage; load average {os.getloadavg()[0]:.2f}\n"
    )
    print(
        "| pair | stage | ms per step, released / kept (mean of blocks) | speed-up "
        "| page faults per step, released / kept | peak RSS MB, released / kept |"
    )
    print("|---:|---:|---|---:|---|---|")
    ratios = {1: [], 2: []}
    for pair in range(args.pairs):
        order = (False, True) if pair % 2 == 0 else (True, False)
        runs = {keep: run_child(args, keep) for keep in order}
        if not runs[True]["kept"]:
            sys.exit("keep_freed_memory() changed nothing here (malloc is not glibc's)")
        for stage in (1, 2):
            off, on = (runs[k][f"stage{stage}"] for k in (False, True))
            peaks = " / ".join(f"{runs[k]['peak_mb']:,.0f}" for k in (False, True))
            ratio = sum(off["blocks"]) / sum(on["blocks"])
            ratios[stage].append(ratio)
            print(
                f"| {pair + 1} | {stage} | {statistics.mean(off['blocks']):.1f} / "
                f"{statistics.mean(on['blocks']):.1f} | {ratio:.3f}x | {off['faults']:,.0f} / "
                f"{on['faults']:,.0f} | {peaks} |"
            )
    for stage in (1, 2):
        print(f"\nstage {stage}: median speed-up {statistics.median(ratios[stage]):.3f}x "
              f"(pairs: {', '.join(f'{r:.3f}' for r in ratios[stage])})")  # fmt: skip
    print(f"load average at the end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
