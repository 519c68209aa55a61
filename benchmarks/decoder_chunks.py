"""What the chunked decoder is worth in real training steps, in one process.

    python benchmarks/decoder_chunks.py --data out/real_hn [--config cpu] [--blocks 6]
                                        [--steps 16] [--warm 60]

Runs blocks of real `Trainer.train_step`s at three points of the config's run (an eighth into
stage 1, a sixth into stage 2, and into stage 4, where the decoder is frozen), each block once
with the decoder as whole-frame torch layers under autograd ("whole": `decoder.plain_forward`,
its form until 2026-11-30) and once chunked ("chunked": `Decoder.forward`, `decoder.CHUNK`
texels a pass), in turn on the same steps (frames and levels), and prints milliseconds per
step and the median over blocks of the speed-up. Then the decoder alone, forward and backward
on the LOD-0 texels of the first training frame, for a few chunk sizes against whole, the
median of `--repeats` rounds taken in turn. The avatar trains through the blocks (untrained
from the config; `--warm` untimed steps before each point fill the tables).
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

from archhead_addon.heap import keep_freed_memory
from archhead_addon.threads import choose_openmp_waiting, limit_thread_environment

CHUNK_SIZES = (1024, 2048, 3072, 4096, 8192)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, required=True, help="a tracked subject folder")
    p.add_argument("--config", default="cpu", help="training config file or preset")
    p.add_argument("--blocks", type=int, default=6, help="blocks per variant and point")
    p.add_argument("--steps", type=int, default=16, help="steps per block")
    p.add_argument("--warm", type=int, default=60, help="untimed steps before each point")
    p.add_argument("--repeats", type=int, default=15, help="rounds of the decoder alone")
    args = p.parse_args(argv)
    keep_freed_memory()  # as the training command does
    choose_openmp_waiting()
    limit_thread_environment()

    import torch

    from archhead_addon.avatar import decoder as decoder_module
    from archhead_addon.train.__main__ import parse_args, setup
    from archhead_addon.train.progress import Progress

    with tempfile.TemporaryDirectory() as tmp:  # nothing is saved: the steps are called alone
        train_args = ["--data", str(args.data), "--out", str(Path(tmp) / "run")]
        trainer = setup(parse_args([*train_args, "--config", args.config]), Progress(None))
    decoder = trainer.avatar.decoder

    def switch(variant: str) -> None:
        if variant == "whole":
            decoder.forward = lambda texel, frame: decoder_module.plain_forward(
                decoder, texel, frame
            )
        else:
            decoder.__dict__.pop("forward", None)

    print(
        f"# Chunked decoder: {args.data} ({len(trainer.frames)} training frames), config "
        f"{args.config}, {torch.get_num_threads()} threads, chunks of {decoder_module.CHUNK}, "
        f"{args.blocks} blocks of {args.steps} steps per variant and point; load average "
        f"{os.getloadavg()[0]:.2f}\n"
    )
    print("| point | variant | ms per step, each block | median | speed-up over whole |")
    print("|---|---|---|---:|---:|")
    cfg = trainer.config
    later = cfg.stage1_steps + cfg.stage2_steps + cfg.stage3_steps
    points = {
        "stage 1": cfg.stage1_steps // 8,
        "stage 2": cfg.stage1_steps + cfg.stage2_steps // 6,
        "stage 4": later + cfg.stage4_steps // 6,
    }
    for point, first in points.items():
        if point == "stage 4" and not cfg.stage4_steps:
            continue
        switch("chunked")
        trainer.step = first
        for _ in range(args.warm):
            trainer.train_step()
        first += args.warm
        ms = {"whole": [], "chunked": []}
        for block in range(args.blocks):
            for variant in ms:
                switch(variant)
                trainer.step = first + block * args.steps
                start = time.perf_counter()
                for _ in range(args.steps):
                    trainer.train_step()
                ms[variant].append(1e3 * (time.perf_counter() - start) / args.steps)
        switch("chunked")
        for variant, values in ms.items():
            ratio = statistics.median(w / x for w, x in zip(ms["whole"], values, strict=True))
            blocks = " / ".join(f"{x:.1f}" for x in values)
            print(
                f"| {point} | {variant} | {blocks} | {statistics.median(values):.1f} "
                f"| {ratio:.3f}x |"
            )
    decoder_alone(trainer, decoder_module, args.repeats)
    print(f"\nload average at the end {os.getloadavg()[0]:.2f}")


def decoder_alone(trainer, decoder_module, repeats: int) -> None:
    """The decoder's forward and backward on one frame's LOD-0 inputs, whole and chunked."""
    import torch

    avatar = trainer.avatar
    decoder = avatar.decoder
    decoder.requires_grad_(True)
    frame = trainer.frames[0]
    inputs = {}

    def capture(texel, frame_vector):
        inputs.update(texel=[x.detach() for x in texel], frame=frame_vector.detach())
        return decoder_module.plain_forward(decoder, texel, frame_vector)

    decoder.forward = capture
    with torch.no_grad():
        avatar(0.0, **frame.codes)
    del decoder.forward
    texel = [x.requires_grad_(i > 0) for i, x in enumerate(inputs["texel"])]  # the PE: none

    def run(forward) -> float:
        start = time.perf_counter()
        out = forward(texel, inputs["frame"])
        sum(v.square().sum() for v in out.values()).backward()
        return 1e3 * (time.perf_counter() - start)

    variants = {"whole": lambda t, f: decoder_module.plain_forward(decoder, t, f)}
    for size in CHUNK_SIZES:
        variants[f"chunks of {size}"] = lambda t, f, size=size: chunked(decoder, t, f, size)
    ms = {name: [] for name in variants}
    for _ in range(3):
        for forward in variants.values():
            run(forward)
    for _ in range(repeats):
        for name, forward in variants.items():
            ms[name].append(run(forward))
    print(
        f"\nThe decoder alone, forward and backward, {len(texel[0])} texels (LOD 0), "
        f"median of {repeats} rounds:\n"
    )
    print("| decoder | ms | speed-up over whole (median of the rounds) |")
    print("|---|---:|---:|")
    for name, values in ms.items():
        ratio = statistics.median(w / x for w, x in zip(ms["whole"], values, strict=True))
        print(f"| {name} | {statistics.median(values):.1f} | {ratio:.2f}x |")


def chunked(decoder, texel, frame, size: int):
    from archhead_addon.avatar import decoder as decoder_module

    saved, decoder_module.CHUNK = decoder_module.CHUNK, size
    try:
        return decoder.forward(texel, frame)
    finally:
        decoder_module.CHUNK = saved


if __name__ == "__main__":
    main()
