"""Evaluate a trained avatar on its test frames (those its run held out: the last 10 % of DIR's
frames, or every tenth with `--holdout interleaved`, as RUN/config.json says):

    python -m archhead_addon.evaluate --avatar RUN/avatar.npz --data DIR --out EVAL
        [--lods 0,0.25,0.5,0.75,1 | --lods 0:1:0.05] [--precisions fp32,fp16]
        [--resolution N] [--flame FILE] [--split test|train] [--frames N] [--mask head|person]
        [--holdout last|interleaved] [--cut none|region]
        [--drive SEQ [--drive-lod L] [--drive-frames N]]

Writes EVAL/metrics.csv and EVAL/metrics.md (L1, PSNR, SSIM, ST-LPIPS, Gaussian count and
render milliseconds per LOD and precision, and the LOD 1 : LOD 0 ratios beside the paper's),
EVAL/error_vs_time.png, EVAL/lods.png (the first test frame: truth, then each LOD) and
EVAL/sheet.png (up to SHEET_ROWS test frames spread over the split, each a row: truth, then
the levels of SHEET_LODS that were evaluated).
--drive renders the avatar driven by another tracked sequence (any supported format) into
EVAL/reenact/ (cross-identity reenactment). Every metric is given over the whole frame
(the masks leave the background exact) and over the tracked head without its neck. The
resolution defaults to the training run's (RUN/config.json); so do the masks, the held-out
frames (`--holdout`: an avatar moved away from its run's config.json says which) and what the
renders are cut to (`--cut region`: the tracking's head-and-neck region, as the run
trained). `--split train` scores the frames the avatar was fitted to (how well it fits,
against how well it generalises); `--frames N` takes N frames evenly spread over the split.
A run that refined its tracking (`lr.codes`) is scored with RUN/tracking_refined.npz: its
training frames with the codes they were trained with, its held-out frames as tracked. Exit
status 2: bad input.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..io.cli import run_command
from ..io.errors import InputError
from ..threads import choose_openmp_waiting
from ..train.config import CUTS, HOLDOUTS, MASKS
from ..train.run_folder import RunFolder

SHEET_ROWS, SHEET_LODS = 4, (0.0, 0.5, 1.0)  # EVAL/sheet.png: test frames by levels


def _lods(text: str) -> list[float]:
    """Comma-separated levels, or FIRST:LAST:STEP (0:1:0.05 is the 21 levels 0, 0.05, ...)."""
    try:
        if ":" in text:
            first, last, step = (float(x) for x in text.split(":"))
            count = round((last - first) / step) + 1 if step > 0 else 0
            lods = [round(first + i * step, 6) for i in range(count)]
        else:
            lods = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        lods = []
    if not lods or any(not 0 <= lod <= 1 for lod in lods):
        raise argparse.ArgumentTypeError(f"levels of detail in [0, 1], got {text!r}")
    return lods


def _positive(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"a whole number >= 1, got {text!r}")
    return value


def _precisions(text: str) -> list[str]:
    names = text.split(",")
    if not names or any(n not in ("fp32", "fp16") for n in names):
        raise argparse.ArgumentTypeError(f"fp32 and / or fp16, got {text!r}")
    return names


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="python -m archhead_addon.evaluate", description=__doc__.split("\n\n")[0]
    )
    p.add_argument("--avatar", type=Path, required=True, help="avatar checkpoint (.npz)")
    p.add_argument("--data", type=Path, required=True, help="the data folder it trained on")
    p.add_argument("--out", type=Path, required=True, help="folder for tables and images")
    p.add_argument(
        "--lods",
        type=_lods,
        default=[0.0, 0.25, 0.5, 0.75, 1.0],
        help="levels of detail: a list (0,0.5,1) or FIRST:LAST:STEP (0:1:0.05); "
        "default 0,0.25,0.5,0.75,1",
    )
    p.add_argument(
        "--precisions",
        type=_precisions,
        default=["fp32", "fp16"],
        help="decode precisions, fp32 and / or fp16 (default fp32,fp16)",
    )
    p.add_argument(
        "--resolution", type=int, help="image size (longer side); default: the training run's"
    )
    p.add_argument("--flame", type=Path, help="FLAME model file (default: the built-in head)")
    p.add_argument(
        "--split",
        choices=("test", "train"),
        default="test",
        help="the run's held-out frames (default) or its training frames",
    )
    p.add_argument(
        "--frames",
        type=_positive,
        help="N frames evenly spread over the split (with --split train and the run's own "
        "--frames N: the very frames it fitted)",
    )
    p.add_argument(
        "--mask",
        choices=MASKS,
        help="which masks cut the truth: head and neck, or the whole person (default: the run's)",
    )
    p.add_argument(
        "--holdout",
        choices=HOLDOUTS,
        help="which frames the run held out (default: the run's; without its config.json, the "
        "paper's last 10 %%)",
    )
    p.add_argument(
        "--cut",
        choices=CUTS,
        help="cut the renders to the tracking's head-and-neck region, as the truth is "
        "(default: as the run trained)",
    )
    p.add_argument("--drive", type=Path, help="tracked sequence to drive the avatar with")
    p.add_argument(
        "--drive-lod", type=float, default=0.0, help="level of detail of --drive (default 0)"
    )
    p.add_argument("--drive-frames", type=int, help="render only the first N driving frames")
    return p.parse_args(argv)


def run_config(args) -> dict:
    """The training run's config.json beside the avatar ({} when there is none)."""
    config = RunFolder(args.avatar.parent).config
    return json.loads(config.read_text()) if config.is_file() else {}


def run_resolution(args) -> int:
    if args.resolution is not None:
        return args.resolution
    config = run_config(args)
    if "resolution" not in config:
        raise InputError(
            args.avatar.parent,
            None,
            f"no {RunFolder(args.avatar.parent).config.name} of a training run here: pass "
            "--resolution",
        )
    return int(config["resolution"])


def run_holdout(args) -> str:
    """Which frames the run held out: --holdout, else the run's (config.json), else the
    paper's last 10 %, said on stderr (scored on the wrong frames, held-out figures mislead)."""
    if args.holdout:
        return args.holdout
    config = run_config(args)
    if "holdout" not in config:
        print(
            f"evaluate: no {RunFolder(args.avatar.parent).config.name} beside the avatar names "
            "its held-out frames: scoring the last 10 % (pass --holdout interleaved for a run "
            "that held out every tenth)",
            file=sys.stderr,
        )
    return config.get("holdout", "last")


def run_mask(args) -> str:
    """Which masks cut the frames: --mask, else the run's (config.json), else head and neck."""
    return args.mask or run_config(args).get("mask", "head")


def run_cut(args) -> str:
    """What the renders are cut to: --cut, else the run's (config.json), else nothing."""
    return args.cut or run_config(args).get("cut", "none")


def run_tracking(args):
    """The run's refined tracking (train/refine.py) when it wrote one, else None (the data
    folder's): training frames are scored with the codes they were trained with."""
    path = RunFolder(args.avatar.parent).tracking
    if not path.is_file():
        return None
    print(f"evaluate: the run's refined tracking ({path.name}) gives the codes", file=sys.stderr)
    return path


def evaluate(args) -> int:
    import numpy as np

    from ..avatar.runtime import AvatarRuntime
    from ..flame.model import load_model
    from ..sequences import read_sequence
    from ..train.dataset import FrameDataset
    from ..train.perceptual import ShiftTolerantLPIPS
    from .lods import evaluate_lods
    from .reenact import reenact, to_png
    from .report import plot_error_vs_time, write_tables

    model = load_model(args.flame)
    runtime = AvatarRuntime.load(args.avatar, model)
    test = FrameDataset(
        args.data,
        run_resolution(args),
        model,
        split=args.split,
        holdout=run_holdout(args),
        mask=run_mask(args),
        frames=args.frames,
        tracking=run_tracking(args),
    )
    frames = [test[i] for i in range(len(test))]
    first = {}
    sheet_rows = sorted({round(i) for i in np.linspace(0, len(frames) - 1, SHEET_ROWS)})
    sheet = {}

    def keep_images(lod, precision, index, rgb):
        if precision != args.precisions[0]:
            return
        if index == 0:
            first[lod] = rgb
        if index in sheet_rows and lod in SHEET_LODS:
            sheet[index, lod] = rgb

    results = evaluate_lods(
        runtime,
        frames,
        test.size,
        test.background,
        ShiftTolerantLPIPS(),
        args.lods,
        args.precisions,
        keep_images,
        cut=run_cut(args) == "region",
    )
    title = (
        f"{args.avatar.name}: {len(frames)} {args.split} frames of {args.data.name}, "
        f"{test.size[1]}x{test.size[0]} px"
    )
    write_tables(args.out, results, title)
    plot_error_vs_time(args.out / "error_vs_time.png", results, title)
    to_png(args.out / "lods.png", np.concatenate([frames[0]["image"], *first.values()], 1))
    columns = [lod for lod in SHEET_LODS if lod in args.lods]
    rows = [
        np.concatenate([frames[i]["image"], *(sheet[i, lod] for lod in columns)], 1)
        for i in sheet_rows
    ]
    to_png(args.out / "sheet.png", np.concatenate(rows, 0))
    print((args.out / "metrics.md").read_text())
    if args.drive is not None:
        driver = read_sequence(args.drive)
        paths = reenact(
            runtime,
            driver,
            args.out / "reenact",
            test.size,
            test.background,
            (frames[0]["K"], frames[0]["w2c"]),
            args.drive_lod,
            args.drive_frames,
        )
        print(f"reenactment: {len(paths)} frames driven by {args.drive} in {args.out / 'reenact'}")
    return 0


def main(argv=None) -> int:
    args = parse_args(argv)
    choose_openmp_waiting()  # before torch loads (threads.py)
    return run_command(lambda: evaluate(args))


if __name__ == "__main__":
    sys.exit(main())
