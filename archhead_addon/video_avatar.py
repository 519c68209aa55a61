"""`python -m archhead_addon avatar VIDEO --out DIR`: a video to an avatar in one command.

Stages, each the project's own command in a child process (its progress on this terminal,
Ctrl-C stops it where it would stop alone):
  1. track VIDEO into DIR/data (skipped when DIR/data holds a finished tracking: the tracker
     writes its folder whole or not at all);
  2. train DIR/data into DIR/run (resumed from its last checkpoint when a run was stopped or
     killed; skipped when finished); with `--minutes M`, within what is left of M minutes
     from the command's start, the preset's steps shortened to fit (train/time_limit.py).
Run it again after a quit or a crash and it carries on from the stage it reached. The last
lines say how to bring the head and the avatar into Blender (the add-on's Avatar from Video
runs the same stages and loads them itself). Ctrl-C stops the stage running as it would stop
alone: training saves its checkpoint first.
"""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

from .io.errors import InputError
from .threads import choose_openmp_waiting
from .track.cli import add_frame_flags
from .train.config import DEFAULT_PRESET, PRESETS, TrainConfig
from .train.dataset import TRACKING_FILE
from .train.run_folder import RunFolder

DATA, RUN = "data", "run"
MIN_TRAINING_MINUTES = 1.0  # less than this left of --minutes trains nothing worth loading


def add_avatar(commands) -> None:
    p = commands.add_parser(
        "avatar",
        help="a video to a trained avatar: track, then train (resumable)",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument("video", help="video file or folder of numbered images")
    p.add_argument("--out", required=True, type=Path, help="folder for data/ and run/")
    p.add_argument(
        "--preset",
        default=DEFAULT_PRESET,
        help=f"training preset ({', '.join(PRESETS)}; default {DEFAULT_PRESET}) or config "
        "file, as train's --config (docs/training.md)",
    )
    p.add_argument("--flame", help="FLAME model file (default: the built-in head)")
    add_frame_flags(p)
    p.add_argument(
        "--minutes",
        type=float,
        default=0.0,
        help="finish within M minutes, training on what tracking leaves of them, the "
        "preset's steps shortened to fit (default 0: the preset's steps)",
    )
    p.add_argument(
        "--progress-json", action="store_true", help="each stage's JSON progress on stdout"
    )
    p.set_defaults(run=run_avatar)


def stages_done(out: Path) -> dict[str, bool]:
    """Which stages a folder has finished: tracked, trained."""
    data, run = out / DATA, RunFolder(out / RUN)
    trained = False
    if run.manifest.is_file():
        state = json.loads(run.manifest.read_text())
        trained = state.get("step") == state.get("total_steps") and run.avatar.is_file()
    return {"tracked": (data / TRACKING_FILE).is_file(), "trained": trained}


def track_command(args) -> list[str]:
    command = [sys.executable, "-m", "archhead_addon", "track", str(args.video)]
    command += ["--out", str(args.out / DATA)]
    if args.flame:
        command += ["--flame", str(args.flame)]
    if args.frames:
        command += ["--frames", str(args.frames)]
    command += ["--frame-budget", str(args.frame_budget)]
    return command + (["--progress-json"] if args.progress_json else [])


def train_command(args, minutes: float = 0.0) -> list[str]:
    """The training stage's command; `minutes`: its time limit (0: none)."""
    command = [sys.executable, "-m", "archhead_addon.train", "--data", str(args.out / DATA)]
    command += ["--out", str(args.out / RUN)]
    if RunFolder(args.out / RUN).state.is_file():
        command.append("--resume")
    else:
        command += ["--config", args.preset, "--holdout", "interleaved"]
    if args.flame:
        command += ["--flame", str(args.flame)]
    if minutes:
        command += ["--minutes", f"{minutes:.3f}"]
    return command + (["--progress-json"] if args.progress_json else [])


def minutes_for_training(minutes: float, started: float) -> float:
    """What a time limit of `minutes` from `started` (time.monotonic()) leaves to training
    (0: no limit); ValueError when tracking left less than MIN_TRAINING_MINUTES."""
    if not minutes:
        return 0.0
    left = minutes - (time.monotonic() - started) / 60
    if left < MIN_TRAINING_MINUTES:
        raise ValueError(
            f"tracking took {minutes - left:.1f} min of the {minutes:g}-minute time limit, "
            "which leaves no time to train; run it again on the same output folder (the "
            "tracking is kept): the limit counts from that start"
        )
    return left


def _run_stage(command: list[str]) -> int:
    """The stage's exit status. A SIGINT to this process (Ctrl-C reaches both; Blender's
    Cancel only this one) is passed on and the stage is waited for while it saves its
    checkpoint: `subprocess.run` would kill it a quarter of a second later."""
    child = subprocess.Popen(command)
    previous = signal.signal(signal.SIGINT, lambda signum, frame: child.send_signal(signum))
    try:
        return child.wait()
    finally:
        signal.signal(signal.SIGINT, previous)


def run_avatar(args) -> int:
    args.started = time.monotonic()
    if not (args.minutes >= 0 and math.isfinite(args.minutes)):
        print(f"avatar: --minutes: must be a number >= 0, got {args.minutes}", file=sys.stderr)
        return 2
    if not RunFolder(args.out / RUN).state.is_file():  # (a resumed run keeps its own)
        try:  # a bad config file is said now, not after the tracking's minutes
            with warnings.catch_warnings():  # (training warns of what it adjusts, once)
                warnings.simplefilter("ignore")
                TrainConfig.load(args.preset)
        except InputError as exc:
            print(f"avatar: --preset: {exc}", file=sys.stderr)
            return 2
    args.out.mkdir(parents=True, exist_ok=True)
    # One choice for both stages, made before the tracker loads the cores: training, choosing
    # when it starts, would take the tracker's load for other jobs' and let its threads sleep
    # (threads.choose_openmp_waiting: about 1.25x a step on quiet cores). The stages inherit it.
    print(f"avatar: {choose_openmp_waiting()}", file=sys.stderr)
    done = stages_done(args.out)
    for name, finished in (("track", done["tracked"]), ("train", done["trained"])):
        if finished:
            print(f"avatar: {name}: done earlier, kept", file=sys.stderr)
            continue
        if name == "track":
            command = track_command(args)
        else:
            try:
                command = train_command(args, minutes_for_training(args.minutes, args.started))
            except ValueError as exc:
                print(f"avatar: {exc}", file=sys.stderr)
                return 1
        status = _run_stage(command)
        if status:
            print(
                f"avatar: {name} stopped (exit status {status}); run the same command again "
                "to carry on from here",
                file=sys.stderr,
            )
            return status
    run = RunFolder(args.out / RUN)
    print(
        f"avatar: {run.avatar}\nIn Blender: File > Import > Tracked FLAME Sequence "
        f"{args.out / DATA / TRACKING_FILE}, then ArchHead tab > Load Avatar {run.avatar}",
        file=sys.stderr,
    )
    return 0
