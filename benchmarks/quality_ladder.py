"""The quality ladder of one subject (docs/quality.md): how close the avatar comes to the
video, rung by rung, so that the representation's ceiling, the tracking's consistency and
generalisation are told apart.

    python benchmarks/quality_ladder.py --data DIR --out LADDER [--config cpu]
        [--short cpu_short] [--holdout interleaved] [--mask head] [--lods 0,0.5,1]

Rungs (each an avatar trained with the project's own `train`, scored with `evaluate`):
  a  one training frame fitted alone (`--frames 1`, the short preset), scored on it;
  b  ten training frames fitted alone (`--frames 10`, the short preset), scored on them;
  c  the full run (every training frame, `--config`), scored on 30 of its training frames;
  d  the same run on its held-out frames.
Every rung is scored over the whole masked frame and over the tracked head without its neck
(no mask moves the latter). Runs and evaluations already complete in LADDER are reused, so a
killed ladder resumes. Prints the table in Markdown and writes LADDER/ladder.md.
"""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
import time
from pathlib import Path

RUNGS = (  # name, what, training frames (None: all), split, frames scored
    ("a", "one frame fitted alone", 1, "train", None),
    ("b", "ten frames fitted alone", 10, "train", None),
    ("c", "every training frame (30 scored)", None, "train", 30),
    ("d", "held-out frames", None, "test", None),
)


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, required=True, help="a tracked training folder")
    p.add_argument("--out", type=Path, required=True, help="folder for the runs and scores")
    p.add_argument("--config", default="cpu", help="preset or file of the full run (c, d)")
    p.add_argument("--short", default="cpu_short", help="preset or file of rungs a and b")
    p.add_argument("--holdout", default="interleaved", choices=("last", "interleaved"))
    p.add_argument("--mask", default="head", choices=("head", "person"))
    p.add_argument("--lods", default="0,0.5,1", help="levels scored (evaluate's --lods)")
    p.add_argument(
        "--score-only", action="store_true", help="train nothing: rungs without a run say so"
    )
    return p.parse_args(argv)


def _run(command: list[str]) -> float:
    """Run a project command; its seconds."""
    print("$", " ".join(command), flush=True)
    start = time.monotonic()
    subprocess.run(command, check=True)
    return time.monotonic() - start


def _train(args, run: Path, config: str, frames: int | None) -> None:
    if (run / "avatar.npz").is_file() and _finished(run):
        return
    command = [sys.executable, "-m", "archhead_addon.train", "--data", str(args.data)]
    command += ["--out", str(run), "--config", config, "--holdout", args.holdout]
    command += ["--mask", args.mask] + (["--frames", str(frames)] if frames else [])
    if (run / "train_state.pt").is_file():
        command = command[:3] + ["--data", str(args.data), "--out", str(run), "--resume"]
    _run(command)


def _finished(run: Path) -> bool:
    import json

    manifest = run / "checkpoint.json"
    if not manifest.is_file():
        return False
    state = json.loads(manifest.read_text())
    return state.get("step") == state.get("total_steps")


def _evaluate(args, run: Path, split: str, frames: int | None, scored: Path) -> list[dict]:
    table = scored / "metrics.csv"
    # (scored again where an evaluate from before the face region wrote the table)
    if not table.is_file() or "psnr_face" not in table.read_text().partition("\n")[0]:
        command = [sys.executable, "-m", "archhead_addon.evaluate", "--avatar"]
        command += [str(run / "avatar.npz"), "--data", str(args.data), "--out", str(scored)]
        command += ["--split", split, "--lods", args.lods, "--precisions", "fp32"]
        if frames:
            command += ["--frames", str(frames)]
        _run(command)
    with open(table) as f:
        return list(csv.DictReader(f))


def _share(row: dict, key: str) -> str:
    """A share column as a percentage ("-" where an evaluation from before it lacks it)."""
    return f"{100 * float(row[key]):.1f} %" if row.get(key) else "-"


def ladder(args) -> str:
    runs = {1: args.out / "run_1", 10: args.out / "run_10", None: args.out / "run_all"}
    for frames, run in runs.items():
        if not args.score_only:
            _train(args, run, args.short if frames else args.config, frames)
    lods = [float(x) for x in args.lods.split(",")]
    head = " | ".join(f"LOD {lod:g}" for lod in lods)
    lines = [
        f"| rung | frames scored | PSNR {head} | SSIM LOD 0 | ST-LPIPS LOD 0 | head PSNR {head} "
        "| head SSIM LOD 0 | head ST-LPIPS LOD 0 | face PSNR LOD 0 / 1 "
        "| axis ratio > 10, LOD 0 / 1 | rods, LOD 0 / 1 | black, LOD 0 / 1 |",
        "|---" * (10 + 2 * len(lods)) + "|",
    ]
    for name, what, frames, split, scored in RUNGS:
        if not _finished(runs[frames]):
            lines.append(f"| {name}: {what} | {split} | not run |" + " |" * (7 + 2 * len(lods)))
            continue
        rows = _evaluate(args, runs[frames], split, scored or frames, args.out / f"eval_{name}")
        by_lod = {float(r["lod"]): r for r in rows}
        first, last = by_lod[lods[0]], by_lod[lods[-1]]
        lines.append(
            f"| {name}: {what} | {split} | "
            + " | ".join(f"{float(by_lod[lod]['psnr']):.2f}" for lod in lods)
            + f" | {float(first['ssim']):.3f} | {float(first['st_lpips']):.3f} | "
            + " | ".join(f"{float(by_lod[lod]['psnr_head']):.2f}" for lod in lods)
            + f" | {float(first['ssim_head']):.3f} | {float(first['st_lpips_head']):.3f} | "
            f"{float(first['psnr_face']):.2f} / {float(last['psnr_face']):.2f} | "
            f"{_share(first, 'needles')} / {_share(last, 'needles')} | "
            f"{_share(first, 'rods')} / {_share(last, 'rods')} | "
            f"{_share(first, 'black')} / {_share(last, 'black')} |"
        )
    table = "\n".join(lines)
    (args.out / "ladder.md").write_text(
        f"# Quality ladder of {args.data} ({args.mask} masks, {args.holdout} holdout)\n\n{table}\n"
    )
    return table


def main(argv=None) -> None:
    args = parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    print(ladder(args))


if __name__ == "__main__":
    main()
