"""Where a whole training run's wall time goes: its steps stage by stage (mean, median, tail)
and its checkpoints, from the run's own progress events stamped with the wall clock as they
arrive.

    python benchmarks/step_times.py --log LOG [--minutes M] [--config PRESET] -- TRAIN ARGS...
    python benchmarks/step_times.py --log LOG [--config PRESET]

The first form runs `python -m archhead_addon.train TRAIN ARGS --progress-json`, writes each
event to LOG (gzip where LOG ends in .gz) as "WALL_SECONDS JSON", stops the run with Ctrl-C's
signal after M minutes (it saves and says "interrupted"), then reports; the second reports an
existing LOG. The step events' own `elapsed_seconds` count the steps alone, to 0.1 s: the
stamps are what time one step and what a checkpoint adds (the gap across a checkpoint event
less a plain step). Prints one Markdown table and, given the run's preset or config file
(`--config`), the whole run's time at these rates.
"""

from __future__ import annotations

import argparse
import gzip
import json
import signal
import subprocess
import sys
import time
from pathlib import Path


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--log", type=Path, required=True, help="the stamped events (.gz: gzip)")
    p.add_argument("--minutes", type=float, help="stop the run after this long")
    p.add_argument("--config", help="the run's preset or file: its whole time at these rates")
    p.add_argument("train", nargs="*", help="after --: the training command's arguments")
    return p.parse_args(argv)


def _open(path: Path, mode: str):
    return gzip.open(path, mode + "t") if path.suffix == ".gz" else path.open(mode)


def record(log: Path, train_args: list[str], minutes: float | None) -> int:
    """Run the training, stamping each event line on arrival; its exit status."""
    command = [sys.executable, "-m", "archhead_addon.train", *train_args, "--progress-json"]
    deadline = None if minutes is None else time.monotonic() + 60 * minutes
    with (
        _open(log, "w") as out,
        subprocess.Popen(command, stdout=subprocess.PIPE, text=True) as run,
    ):
        for line in run.stdout:
            out.write(f"{time.time():.4f} {line}")
            if deadline is not None and time.monotonic() > deadline:
                run.send_signal(signal.SIGINT)  # the run saves a checkpoint and stops
                deadline = None
        return run.wait()


def read(log: Path) -> list[tuple[float, dict]]:
    events = []
    with _open(log, "r") as lines:
        for line in lines:
            stamp, _, text = line.partition(" ")
            if text.startswith("{"):
                events.append((float(stamp), json.loads(text)))
    return events


def _quantile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(int(q * len(ordered)), len(ordered) - 1)]


def summarise(events: list[tuple[float, dict]]) -> dict:
    """Per stage the seconds between consecutive step events with no checkpoint between them;
    a checkpoint's cost as its gap less the median plain step of its stage."""
    plain: dict[int, list[float]] = {}
    across: list[tuple[int, float]] = []  # (stage, gap) of steps that follow a checkpoint
    last, checkpoint = None, False
    for stamp, event in events:
        kind = event.get("event")
        if kind == "checkpoint":
            checkpoint = True
        elif kind == "step":
            if last is not None:
                gap = stamp - last
                if checkpoint:
                    across.append((event["stage"], gap))
                else:
                    plain.setdefault(event["stage"], []).append(gap)
            last, checkpoint = stamp, False
    timed = [(stamp, e) for stamp, e in events if e.get("event") == "step"]
    if not timed:
        raise ValueError("no step events in the log")
    (first, _), (last_step, final) = timed[0], timed[-1]
    stages = {
        stage: {
            "steps": len(gaps),
            "mean_ms": 1e3 * sum(gaps) / len(gaps),
            "median_ms": 1e3 * _quantile(gaps, 0.5),
            "p90_ms": 1e3 * _quantile(gaps, 0.9),
            "p99_ms": 1e3 * _quantile(gaps, 0.99),
            "max_ms": 1e3 * max(gaps),
        }
        for stage, gaps in sorted(plain.items())
    }
    costs = [gap - stages[stage]["median_ms"] / 1e3 for stage, gap in across if stage in stages]
    return {
        "stages": stages,
        "checkpoints": len(costs),
        "checkpoint_ms": 1e3 * sum(costs) / len(costs) if costs else 0.0,
        "step": final["step"],
        "total": final["total"],
        "wall_s": last_step - first,
        "elapsed_s": final["elapsed_seconds"],
        "start": next((e for _, e in events if e.get("event") == "start"), {}),
    }


def report(summary: dict, config=None):
    """The table, and the whole run's minutes given its TrainConfig."""
    start = summary["start"]
    print(
        f"{summary['step']:,} of {summary['total']:,} steps on {start.get('device', '?')} "
        f"({start.get('renderer', '?')}), {summary['wall_s']:.1f} s of wall time from the first "
        f"step to the last, {summary['elapsed_s']:.1f} s of it in the steps themselves",
        "",
        "| stage | steps timed | mean ms | median ms | p90 ms | p99 ms | max ms |",
        "|---:|---:|---:|---:|---:|---:|---:|",
        sep="\n",
    )
    for stage, s in summary["stages"].items():
        print(
            f"| {stage} | {s['steps']:,} | {s['mean_ms']:.1f} | {s['median_ms']:.1f} | "
            f"{s['p90_ms']:.1f} | {s['p99_ms']:.1f} | {s['max_ms']:.1f} |"
        )
    print(
        f"\na checkpoint adds {summary['checkpoint_ms']:.0f} ms "
        f"(the mean over {summary['checkpoints']} checkpoints)"
    )
    stage_steps = {} if config is None else dict(enumerate(config.stage_steps, start=1))
    if stage_steps and all(k in summary["stages"] for k, n in stage_steps.items() if n):
        steps_s = sum(n * summary["stages"][k]["mean_ms"] for k, n in stage_steps.items() if n)
        saves = config.total_steps // config.checkpoint_every
        whole = (steps_s + saves * summary["checkpoint_ms"]) / 60e3
        print(
            f"the whole run at these rates: {whole:.1f} min ({steps_s / 60e3:.1f} in steps, "
            f"{saves * summary['checkpoint_ms'] / 60e3:.1f} in {saves} checkpoints)"
        )


def main(argv=None) -> int:
    args = parse_args(argv)
    status = record(args.log, args.train, args.minutes) if args.train else 0
    summary = summarise(read(args.log))
    from archhead_addon.train.config import TrainConfig

    report(summary, TrainConfig.load(args.config) if args.config else None)
    return status


if __name__ == "__main__":
    sys.exit(main())
