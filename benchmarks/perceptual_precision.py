"""ST-LPIPS in float32 and under bfloat16 autocast, back to back in one process.

    python benchmarks/perceptual_precision.py [--size 256] [--rounds 14] [--threads 2]

One render's perceptual term as training takes it: `compare` against a shared reference,
forward and backward to the image, on a random image pair of --size pixels. Prints the
median milliseconds of each precision (the two alternate, round by round) and how far the
bfloat16 distance and image gradient are from float32's: whether lower precision makes the
term cheaper per unit of quality (docs/training_profile.md).
"""

from __future__ import annotations

import argparse
import statistics
import time


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--rounds", type=int, default=14)
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)

    import torch

    from archhead_addon.train.perceptual import ShiftTolerantLPIPS

    torch.set_num_threads(args.threads)
    lpips = ShiftTolerantLPIPS()
    rng = torch.Generator().manual_seed(0)
    image = torch.rand(args.size, args.size, 3, generator=rng, requires_grad=True)
    target = torch.rand(args.size, args.size, 3, generator=rng)
    reference = lpips.reference(target.permute(2, 0, 1)[None])

    def term(dtype):
        image.grad = None
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=dtype is torch.bfloat16):
            distance = lpips.compare(image.permute(2, 0, 1)[None], reference)
        distance.float().sum().backward()
        return float(distance.detach()), image.grad.clone()

    precisions = {"float32": torch.float32, "bfloat16 autocast": torch.bfloat16}
    times = {name: [] for name in precisions}
    for i in range(args.rounds + 2):  # two untimed rounds first
        for name, dtype in precisions.items():
            start = time.perf_counter()
            term(dtype)
            if i >= 2:
                times[name].append(1e3 * (time.perf_counter() - start))
    (d32, g32), (d16, g16) = (term(dtype) for dtype in precisions.values())
    print(f"# ST-LPIPS term, {args.size}² image, {args.threads} threads, {args.rounds} rounds\n")
    print("| precision | ms (median) | distance | gradient error vs float32 |")
    print("|---|---:|---:|---:|")
    base = statistics.median(times["float32"])
    for name, (d, g) in zip(precisions, ((d32, g32), (d16, g16)), strict=True):
        error = float((g - g32).norm() / g32.norm())
        print(f"| {name} | {statistics.median(times[name]):.1f} | {d:.5f} | {error:.1%} |")
    print(f"\nfloat32 / bfloat16: {base / statistics.median(times['bfloat16 autocast']):.2f}x")


if __name__ == "__main__":
    main()
