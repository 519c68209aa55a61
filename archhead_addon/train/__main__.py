"""Train an avatar: python -m archhead_addon.train --data DIR --out DIR [--config F]
[--resume] [--progress-json] [--flame FILE] [--holdout last|interleaved] [--mask head|person]
[--frames N] [--minutes M]

DIR holds frames/, optional masks/ and parts/, and tracking.npz (train/dataset.py). The run
writes OUT/avatar.npz (the avatar), OUT/train_state.pt (to resume), OUT/config.json and
OUT/checkpoint.json (which vouches for the other three), every `checkpoint_every` steps and at
the end. Ctrl-C (SIGINT) or SIGTERM finishes the current step, saves and exits with status
130; a second Ctrl-C stops at once. --resume first rewrites the files that a kill left behind
the state. Exit status 0: trained, and the four files agree; 2: bad input; 1: they do not.

torch loads only after the arguments are read, and after `threads.choose_openmp_waiting` has
chosen how its OpenMP threads wait: a short spin on quiet cores, sleeping at once on busy ones
(docs/training.md).
"""

from __future__ import annotations

import argparse
import signal
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from ..heap import keep_freed_memory
from ..io.atomic import remove_stale_temporaries
from ..io.errors import InputError, InputWarning
from ..threads import choose_openmp_waiting, limit_thread_environment
from .config import DEFAULT_PRESET, HOLDOUTS, MASKS, PRESETS, TrainConfig
from .progress import DONE, ERROR, START, Progress
from .progress import INTERRUPTED as INTERRUPTED_EVENT
from .run_folder import RunFolder

if TYPE_CHECKING:
    from .loop import Trainer

INTERRUPTED = 130  # the shell's status for a run stopped by SIGINT
# seconds of the process that a time limit counts outside `main`: the interpreter's start
# and, after the last checkpoint, the files' check and the exit (2.6 s in a `cpu` run here)
OUTSIDE_MAIN = 5.0


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="python -m archhead_addon.train", description=__doc__.split("\n\n")[0]
    )
    p.add_argument("--data", type=Path, required=True, help="training data folder")
    p.add_argument("--out", type=Path, required=True, help="output folder of the run")
    p.add_argument(
        "--config",
        default=DEFAULT_PRESET,
        help=f"config file, or a preset: "
        f"{', '.join(PRESETS)} (default: {DEFAULT_PRESET}); ignored with --resume, "
        "which uses the run's own",
    )
    p.add_argument(
        "--resume", action="store_true", help="continue the run in --out from its last checkpoint"
    )
    p.add_argument(
        "--progress-json",
        action="store_true",
        help="one JSON object per line on "
        "stdout (events: start, step, checkpoint, done, interrupted, error)",
    )
    p.add_argument("--flame", type=Path, help="FLAME model file (default: the built-in head)")
    p.add_argument(
        "--holdout",
        choices=HOLDOUTS,
        help="the test frames kept out of training: the last 10 %% (the paper's, default) or "
        "every tenth frame; overrides the config's 'holdout'",
    )
    p.add_argument(
        "--mask",
        choices=MASKS,
        help="which masks cut the frames: the tracker's head and neck (default) or the whole "
        "person (shoulders too); overrides the config's 'mask'",
    )
    p.add_argument(
        "--frames",
        type=int,
        help="train on N frames of the training split, evenly spread (the quality ladder's "
        "one- and ten-frame fits); overrides the config's 'frames'",
    )
    p.add_argument(
        "--minutes",
        type=float,
        help="end within M minutes of this command's start, every stage's steps shortened "
        "in one proportion (0: the config's steps; docs/training.md); overrides the "
        "config's 'minutes'. A resumed run takes the steps its checkpoint fitted, and a "
        "limit only when given one here",
    )
    args = p.parse_args(argv)
    args.started = time.monotonic()  # a time limit counts from here (loading included)
    return args


class StopFlag:
    """Set by the first SIGINT / SIGTERM; the second SIGINT raises KeyboardInterrupt."""

    def __init__(self):
        self.set = False

    def __call__(self) -> bool:
        return self.set

    def install(self) -> dict:
        """Install the handlers; returns the previous ones (for `restore`)."""

        def handler(signum, frame):
            if self.set and signum == signal.SIGINT:
                raise KeyboardInterrupt
            self.set = True

        return {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}

    @staticmethod
    def restore(previous: dict) -> None:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def setup(args, progress: Progress) -> Trainer:
    """The trainer of a new or resumed run; bad input raises InputError or ValueError."""
    import torch

    from ..flame.model import load_model
    from . import loop
    from .dataset import FrameDataset

    state_path = RunFolder(args.out).state
    if args.resume and not state_path.is_file():
        raise InputError(args.out, None, f"nothing to resume: no {state_path.name} here")
    if not args.resume and state_path.exists():
        raise InputError(
            args.out,
            None,
            "holds a training run: pass --resume to continue it, or choose another --out",
        )
    removed = remove_stale_temporaries(args.out)  # the folder is this process's from here
    if removed:
        progress.message(f"removed {len(removed)} temporary files of killed writes")
    state = loop.load_state(state_path) if args.resume else None
    if state is None:
        config = TrainConfig.load(args.config)
        overrides = {"holdout": args.holdout, "mask": args.mask, "frames": args.frames}
        config = replace(config, **{k: v for k, v in overrides.items() if v is not None})
    else:
        config = loop.state_config(state, state_path)
    if args.minutes is not None:
        config = replace(config, minutes=args.minutes)
    if config.threads:  # held to the cores (TrainConfig.read)
        torch.set_num_threads(config.threads)
    device = loop.resolve_device(config.device)
    model = load_model(args.flame)
    dataset = FrameDataset(
        args.data,
        config.resolution,
        model,
        split="train",
        holdout=config.holdout,
        mask=config.mask,
        frames=config.frames or None,
    )
    frames = loop.frames_on_device(dataset, device)
    if state is not None:
        trainer = loop.Trainer.resume(
            state, args.out, frames, model, dataset.background, device, config, dataset.sequence
        )
        for problem in trainer.repair():
            progress.message(f"repaired: {problem}; rewritten from {state_path.name}")
    else:
        trainer = loop.Trainer.create(
            config,
            frames,
            model,
            dataset.sequence.shape[0],
            args.out,
            dataset.background,
            device,
            identity_offset=dataset.sequence.static_offset,
            sequence=dataset.sequence,
        )
    # a resumed run keeps the steps its checkpoint fitted, and takes a limit anew only when
    # given one (its config's says what fitted them)
    if args.minutes is not None:
        minutes = args.minutes
    else:
        minutes = 0.0 if state is not None else config.minutes
    trainer.limit_time(args.started - OUTSIDE_MAIN, minutes)
    progress.event(
        START,
        step=trainer.step,
        total=config.total_steps,
        device=str(device),
        renderer=trainer.backend,
        frames=len(frames),
        resolution=list(dataset.size),
    )
    progress.message(
        f"training on {len(frames)} frames of {dataset.size[1]}x"
        f"{dataset.size[0]} px, {device}, renderer {trainer.backend}"
        + (f", resumed at step {trainer.step}" if state is not None else "")
        + (f", within {minutes:g} min" if minutes else "")
    )
    return trainer


def train(trainer: Trainer, progress: Progress, stop: StopFlag) -> int:
    finished = trainer.run(progress.step, progress.checkpoint, stop, progress.message)
    folder = RunFolder(trainer.out_dir)
    problems = folder.problems(trainer.step)
    if problems:  # never "done" without the files it promises
        message = f"{folder.root}: the run's files do not agree: {'; '.join(problems)}"
        progress.event(ERROR, message=message)
        progress.message(f"error: {message}")
        return 1
    kind = DONE if finished else INTERRUPTED_EVENT
    avatar = folder.avatar
    total = trainer.config.total_steps
    progress.event(
        kind,
        step=trainer.step,
        total=total,
        avatar=str(avatar),
        elapsed_seconds=round(trainer.elapsed, 1),
    )
    minutes = trainer.elapsed / 60
    progress.message(
        f"{kind} at step {trainer.step}/{total} after {minutes:.1f} min of training; "
        f"avatar {avatar}"
    )
    return 0 if finished else INTERRUPTED


def main(argv=None) -> int:
    args = parse_args(argv)
    keep_freed_memory()  # every step takes again what the last one freed (heap.py)
    waiting = choose_openmp_waiting()  # before torch loads OpenMP
    progress = Progress(args.progress_json)
    progress.message(waiting)
    stop = StopFlag()
    previous = stop.install()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always", InputWarning)
            warnings.showwarning = lambda message, *rest: progress.message(f"warning: {message}")
            limit_thread_environment()  # before torch loads OpenMP, too
            try:
                trainer = setup(args, progress)
            except (InputError, ValueError) as exc:
                progress.event(ERROR, message=str(exc))
                progress.message(f"error: {exc}")
                return 2
            return train(trainer, progress, stop)
    finally:
        StopFlag.restore(previous)


if __name__ == "__main__":
    sys.exit(main())
