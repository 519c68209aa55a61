"""What holds a level of detail back: continue a finished (or stopped) run's stage 2 at fixed
levels, with one thing changed, and print its PSNR on training and test frames as it goes.

    python -m archhead_addon.train.probe --run RUN --data DIR [--levels 1] [--steps 1200]
        [--every 400] [--lr-scale 1] [--frame K] [--no-regularisers] [--widen H,C]
        [--threads N] [--flame FILE]

- `--levels`: the levels every step renders (comma-separated), e.g. `1` trains LOD 1 alone.
- `--frame K`: train on training frame K alone (is a level short of capacity, or of a
  function that holds every frame at once?).
- `--no-regularisers`: λ_μ = λ_s = 0 (do the offset and scale terms hold it back?).
- `--widen H,C`: the decoder's heads widened to H (colour head: C) hidden units first, computing
  the same function (new units have zero outgoing weights); Adam starts afresh.
- `--lr-scale`: the learning rates, as a fraction of the config's start values, held constant.

Read only: the run's files are not written. PSNR (dB) is the training renderer's (torch and
the splat kernel), averaged over every 20th training frame (or frame K) and every test frame
(the last 10 %); docs/training.md has what it found on the CPU preset.
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

from ..threads import choose_openmp_waiting

TRAIN_STRIDE = 20  # every 20th training frame is measured (9 of 180)


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="python -m archhead_addon.train.probe", description=__doc__.split("\n\n")[0]
    )
    p.add_argument("--run", type=Path, required=True, help="a training run's folder")
    p.add_argument("--data", type=Path, required=True, help="the run's data folder")
    p.add_argument(
        "--levels", type=_levels, default=[1.0], help="levels of every step (default: 1)"
    )
    p.add_argument("--steps", type=int, default=1200)
    p.add_argument("--every", type=int, default=400, help="measure every N steps")
    p.add_argument("--lr-scale", type=float, default=1.0)
    p.add_argument("--frame", type=int, help="train on this training frame alone")
    p.add_argument("--no-regularisers", action="store_true")
    p.add_argument("--widen", type=_widths, help="hidden widths H,C of the widened heads")
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: its default)")
    p.add_argument("--flame", type=Path, help="FLAME model file (default: the built-in head)")
    args = p.parse_args(argv)
    if args.steps < 0 or args.every < 1 or args.lr_scale <= 0:
        p.error("need --steps >= 0, --every >= 1 and --lr-scale > 0")
    return args


def _levels(text: str) -> list[float]:
    values = [float(v) for v in text.split(",")]
    if not values or any(not 0 <= v <= 1 for v in values):
        raise argparse.ArgumentTypeError(f"levels must be in [0, 1]: {text}")
    return values


def _widths(text: str) -> tuple[int, int]:
    try:
        hidden, colour = (int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected H,C (two integers): {text}") from None
    return hidden, colour


def widen(avatar, hidden: int, colour_hidden: int):
    """A copy of `avatar` whose decoder heads have `hidden` (colour: `colour_hidden`) units per
    hidden layer and which decodes exactly what `avatar` decodes: the old units keep their
    weights, new units take random inputs and feed the outputs with weight zero."""
    import torch

    from ..avatar.config import HEADS
    from ..avatar.model import ArchHeadAvatar

    old = avatar.config
    if hidden < old.hidden or colour_hidden < old.colour_hidden:
        raise ValueError(
            f"cannot narrow the heads ({old.hidden},{old.colour_hidden} -> "
            f"{hidden},{colour_hidden})"
        )
    config = replace(old, hidden=hidden, colour_hidden=colour_hidden)
    wide = ArchHeadAvatar(
        avatar.mesh,
        avatar.identity_shape.cpu().numpy(),
        config,
        avatar.base_model_id,
        avatar.identity_offset,
    ).to(avatar.identity_shape.device)
    wide.features.load_state_dict(avatar.features.state_dict())
    wide.mapping.load_state_dict(avatar.mapping.state_dict())
    old_rows, new_rows = old.head_slices(), config.head_slices()
    with torch.no_grad():
        for name in HEADS:
            n = old_rows[name].stop - old_rows[name].start
            rows = slice(new_rows[name].start, new_rows[name].start + n)
            wide.decoder.first.weight[rows] = avatar.decoder.first.weight[old_rows[name]]
            wide.decoder.first.bias[rows] = avatar.decoder.first.bias[old_rows[name]]
            narrow_head, wide_head = avatar.decoder.heads[name], wide.decoder.heads[name]
            for a, b in zip(narrow_head.hidden, wide_head.hidden, strict=True):
                b.weight[:n, :n] = a.weight
                b.weight[:n, n:] = 0.0  # the old units ignore the new ones
                b.bias[:n] = a.bias
            wide_head.out.weight.zero_()
            wide_head.out.weight[:, :n] = narrow_head.out.weight
            wide_head.out.bias.copy_(narrow_head.out.bias)
    return wide


def mean_psnr(trainer, frames, lod: float) -> float:
    import torch

    from ..evaluate.metrics import psnr

    with torch.no_grad():
        values = [psnr(trainer.render(f, lod)[0].clamp(0, 1), f.image) for f in frames]
    return sum(values) / len(values)


def make_trainer(args):
    """(trainer continuing the run as the options change it, train frames measured, test
    frames). ValueError or InputError on bad input."""
    import torch

    from ..flame.model import load_model
    from ..io.errors import InputError
    from ..threads import thread_count
    from . import loop
    from .dataset import FrameDataset
    from .run_folder import RunFolder

    if args.threads:
        torch.set_num_threads(thread_count(args.threads, "command line", "--threads"))
    state_path = RunFolder(args.run).state
    if not state_path.is_file():
        raise InputError(args.run, None, f"no {state_path.name}: not a training run")
    state = loop.load_state(state_path)
    config = loop.state_config(state, state_path)
    if args.no_regularisers:
        config = replace(config, loss=replace(config.loss, offset=0.0, scale=0.0))
    state["config"] = config.to_json()
    model = load_model(args.flame)
    device = torch.device("cpu")
    train, test = (
        FrameDataset(
            args.data,
            config.resolution,
            model,
            split=split,
            holdout=config.holdout,
            mask=config.mask,
            frames=(config.frames or None) if split == "train" else None,
        )
        for split in ("train", "test")
    )
    frames = loop.frames_on_device(train, device)
    if args.frame is not None:
        if not 0 <= args.frame < len(frames):
            raise ValueError(f"--frame {args.frame}: the run has {len(frames)} training frames")
        frames = [frames[args.frame]]
    trainer = _probe_class().resume(state, args.run, frames, model, train.background, device)
    if args.widen:
        wide = widen(trainer.avatar, *args.widen)
        trainer = _probe_class()(config, frames, wide, args.run, train.background, device)
        trainer.step = int(state["step"])
    trainer.levels, trainer.lr_scale = args.levels, args.lr_scale
    trainer.step = max(trainer.step, config.stage1_steps)  # stage 2: the mapping stays frozen
    return trainer, frames[::TRAIN_STRIDE], loop.frames_on_device(test, device)


@functools.cache
def _probe_class():
    """The Trainer subclass, made on first use: torch loads only after main has set up."""
    from .loop import Trainer

    class Probe(Trainer):
        """A trainer with fixed levels and a constant learning rate."""

        levels: list[float] = [1.0]
        lr_scale: float = 1.0

        def lods(self, step: int) -> list[float]:
            return list(self.levels)

        def learning_rate_factor(self, step: int) -> float:
            return self.lr_scale

        def save(self):  # read only
            raise RuntimeError("the probe does not write the run")

    return Probe


def run(args, out=None) -> list[dict]:
    """Train and measure; one row per measurement (step, then PSNR by split and level)."""
    out = out or sys.stdout
    trainer, train_frames, test_frames = make_trainer(args)
    measured = sorted({0.0, 1.0, *args.levels})
    rows, start = [], time.perf_counter()
    print(
        f"probe {args.run}: levels {args.levels}, {args.steps} steps, "
        f"{len(trainer.frames)} training frame(s), lr x {args.lr_scale}"
        + (", no regularisers" if args.no_regularisers else "")
        + (f", heads widened to {args.widen}" if args.widen else ""),
        file=out,
        flush=True,
    )
    for done in range(args.steps + 1):
        if done % args.every == 0 or done == args.steps:
            row = {"step": done, "seconds": round(time.perf_counter() - start, 1)}
            for split, frames in (("train", train_frames), ("test", test_frames)):
                for lod in measured:
                    row[f"{split} l={lod:g}"] = round(mean_psnr(trainer, frames, lod), 2)
            rows.append(row)
            print(json.dumps(row), file=out, flush=True)
        if done < args.steps:
            trainer.train_step()
    return rows


def main(argv=None) -> int:
    args = parse_args(argv)
    choose_openmp_waiting()  # before torch loads (threads.py)
    from ..io.errors import InputError

    try:
        run(args)
    except (InputError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
