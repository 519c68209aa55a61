"""What training the feature field after stage 2 is worth (docs/quality.md, "Stages 3 and
4"): a finished run of stages 1 and 2, continued in several ways, each scored on held-out
frames.

    python benchmarks/later_stages.py --run RUN --data DATA --out DIR [--variants a,b]
        [--steps 1500]

RUN: a finished run without stages 3 and 4 (a run of the `cpu` preset before them, such as
the README's one command's `run` folder of 2026-11-28); DATA: its tracked folder. Each
variant continues RUN's last checkpoint (or another variant's) in a folder of its own under
DIR and is scored by `evaluate --split test --lods LODS` (a variant whose scores are there
is not run again):

- "run": RUN itself;
- "stage2": `--steps` more whole stage-2 steps (decoder and features) at the rates stage 2
  ended on, from a new Adam;
- "features": every feature level alone, at stage 2's draws, from a new Adam at the feature
  rate stage 2 ended on;
- "sparsest", "sparsest x2": the sparsest level alone, near LOD 1 as the run's band draws
  it (1 - `lod1_band` v²), for `--steps` and twice as many;
- "64 and 32": the two sparsest levels, near LOD 1;
- "features then uniform 0.9" and "features then uniform 0.8": "features", then twice
  `--steps` of the sparsest level alone at levels uniform in [0.9, 1] and [0.8, 1];
- "preset": the trainer resumed with the `cpu` preset's `stage3_steps` and `stage4_steps`
  (or `--preset`'s; Adam's moments carried on): the steps a run of the preset takes after
  its stage 2.

The fresh-Adam variants draw their frames and levels from one seeded generator, so a rerun
takes the same steps. Prints the table (with l = 0.9 / 0.95 when LODS has them) and each
variant's seconds of steps.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import re
import shutil
import sys
import time
from dataclasses import replace
from pathlib import Path

from archhead_addon.heap import keep_freed_memory

# name: (the variant it continues, what trains, times --steps, its levels); "band": the
# run's draw near LOD 1, a number w: uniform in [1 - w, 1]
FRESH_ADAM = {
    "stage2": ("run", "stage2", 1, "stage 2"),
    "features": ("run", "features", 1, "stage 2"),
    "sparsest": ("run", "sparsest", 1, "band"),
    "sparsest x2": ("run", "sparsest", 2, "band"),
    "64 and 32": ("run", "64 and 32", 1, "band"),
    "features then uniform 0.9": ("features", "sparsest", 2, 0.1),
    "features then uniform 0.8": ("features", "sparsest", 2, 0.2),
}
VARIANTS = ("run", *FRESH_ADAM, "preset")
SEED = 7  # the fresh-Adam variants' frames and levels


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run", type=Path, required=True, help="a finished run of stages 1 and 2")
    p.add_argument("--data", type=Path, required=True, help="the run's tracked folder")
    p.add_argument("--out", type=Path, required=True, help="folder of the variants' runs")
    p.add_argument("--variants", default=",".join(VARIANTS), help="comma list of VARIANTS")
    p.add_argument("--steps", type=int, default=1500, help="steps of the fresh-Adam variants")
    p.add_argument("--preset", default="cpu", help="config whose stages 3 and 4 'preset' takes")
    p.add_argument("--lods", default="0,0.5,1", help="levels to score (0, 0.5 and 1 at least)")
    args = p.parse_args(argv)
    args.variants = args.variants.split(",")
    unknown = set(args.variants) - set(VARIANTS)
    if unknown:
        p.error(f"unknown variants {sorted(unknown)}; known: {', '.join(VARIANTS)}")
    return args


def folder_of(out: Path, variant: str) -> Path:
    return out / re.sub(r"[^\w.]+", "_", variant)


def resumed(run: Path, data: Path, out: Path, stages=(0, 0)):
    """The trainer of RUN's last checkpoint, copied into `out`, with stages 3 and 4 set."""
    import torch

    from archhead_addon.flame.model import load_model
    from archhead_addon.train import loop
    from archhead_addon.train.dataset import FrameDataset

    out.mkdir(parents=True, exist_ok=True)
    shutil.copy(run / "train_state.pt", out / "train_state.pt")
    state = loop.load_state(out / "train_state.pt")
    config = loop.state_config(state)
    if state["step"] != config.total_steps or any(config.stage_steps[2:]):
        sys.exit(f"{run}: not a finished run of stages 1 and 2 alone")
    config = replace(config, stage3_steps=stages[0], stage4_steps=stages[1])
    model = load_model(None)
    cpu = torch.device("cpu")
    dataset = FrameDataset(
        data, config.resolution, model, split="train", holdout=config.holdout, mask=config.mask
    )
    frames = loop.frames_on_device(dataset, cpu)
    return loop.Trainer.resume(
        state, out, frames, model, dataset.background, cpu, config, dataset.sequence
    )


def fresh_adam(trainer, variant: str, steps: int) -> None:
    """One of the FRESH_ADAM variants, from where `trainer` stands."""
    import numpy as np
    import torch

    _, part, times, draw = FRESH_ADAM[variant]
    cfg, avatar = trainer.config, trainer.avatar
    end = cfg.lr_final_ratio
    avatar.requires_grad_(False)
    if part == "stage2":
        groups = [(avatar.features, cfg.lr.features), (avatar.decoder, cfg.lr.decoder)]
        params = [{"params": list(m.parameters()), "lr": lr * end} for m, lr in groups]
    else:
        sizes = {
            "features": list(avatar.features),
            "sparsest": [trainer.sparsest],
            "64 and 32": sorted(avatar.features, key=int)[:2],
        }[part]
        params = [{"params": [avatar.features[s] for s in sizes], "lr": cfg.lr.features * end}]
    for group in params:
        for p in group["params"]:
            p.requires_grad_(True)
    adam = torch.optim.Adam(params)
    rng = np.random.default_rng(SEED)
    for _ in range(times * steps):
        frame = trainer.frames[rng.integers(len(trainer.frames))]
        if draw == "band":
            lod = float(1 - cfg.lod1_band * rng.random() ** 2)
        elif draw == "stage 2":  # stage 2's draw, at one of its steps
            lod = trainer.lods(cfg.stage1_steps + int(rng.integers(cfg.stage2_steps)))[0]
        else:
            lod = float(1 - draw * rng.random())
        adam.zero_grad(set_to_none=True)
        rgb, g = trainer.render(frame, lod)
        total, _ = trainer.loss.terms(rgb, frame.image, frame.parts, g, lod, 0.0, None)
        total.backward()
        adam.step()
    trainer.save()


def train(variant: str, args, folder: Path) -> float:
    """Seconds of one variant's steps (and checkpoints), its avatar written to `folder`."""
    from archhead_addon.train.config import TrainConfig

    if variant == "preset":
        trainer = resumed(
            args.run, args.data, folder, TrainConfig.load(args.preset).stage_steps[2:]
        )
    else:
        start = FRESH_ADAM[variant][0]
        origin = args.run if start == "run" else folder_of(args.out, start)
        if not (origin / "train_state.pt").is_file():
            sys.exit(f"'{variant}' continues '{start}': run that variant first")
        trainer = resumed(origin, args.data, folder)
    begin = time.perf_counter()
    if variant == "preset":
        trainer.run(lambda report: None, lambda step, path: None)
    else:
        fresh_adam(trainer, variant, args.steps)
    return time.perf_counter() - begin


def scores(avatar: Path, data: Path, out: Path, lods: str) -> dict[float, dict]:
    """{LOD: metrics.csv row} of `evaluate` on the held-out frames, run in this process (a
    process of its own per variant took longer to start than to score a small subject)."""
    from archhead_addon.evaluate.__main__ import evaluate, parse_args

    if not (out / "metrics.csv").is_file():
        with contextlib.redirect_stdout(io.StringIO()):  # its table: this one has its rows
            evaluate(parse_args(
                ["--avatar", str(avatar), "--data", str(data), "--out", str(out),
                 "--split", "test", "--lods", lods, "--precisions", "fp32"]
            ))  # fmt: skip
    with open(out / "metrics.csv") as f:
        return {float(row["lod"]): row for row in csv.DictReader(f)}


def _column(rows: dict, key: str, lods=(0.0, 0.5, 1.0)) -> str:
    return " / ".join(f"{float(rows[lod][key]):.2f}" for lod in lods)


def main(argv=None) -> None:
    args = parse_args(argv)
    keep_freed_memory()  # as the training command does
    end = {0.9, 0.95} <= {float(x) for x in args.lods.split(",")}
    print(
        "| variant | PSNR LOD 0 / 0.5 / 1 | LOD 1 vs 0 | head PSNR LOD 0 / 0.5 / 1 "
        + ("| l = 0.9 / 0.95 " if end else "")
        + "| face, LOD 0 | s of steps |\n|---|---|---:|---|"
        + ("---|" if end else "")
        + "---:|---:|"
    )
    for variant in args.variants:
        folder = folder_of(args.out, variant)
        seconds = 0.0
        if variant == "run":
            avatar = args.run / "avatar.npz"
        else:
            avatar = folder / "avatar.npz"
            if not (folder / "eval" / "metrics.csv").is_file():
                shutil.rmtree(folder, ignore_errors=True)
                seconds = train(variant, args, folder)
        rows = scores(avatar, args.data, folder / "eval", args.lods)

        psnr = [float(rows[lod]["psnr"]) for lod in (0.0, 1.0)]
        print(
            f"| {variant} | {_column(rows, 'psnr')} | {100 * (psnr[1] / psnr[0] - 1):.1f} % "
            f"| {_column(rows, 'psnr_head')} "
            + (f"| {_column(rows, 'psnr', (0.9, 0.95))} " if end else "")
            + f"| {float(rows[0.0]['psnr_face']):.2f} | {seconds:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
