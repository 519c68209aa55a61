"""ST-LPIPS with its first slice folded (this tree's) and unfolded, back to back in one process.

    python benchmarks/perceptual_fold.py [--size 256] [--rounds 15] [--threads 2]

The perceptual term as a training step takes it: the target's features, then one render's
distance, forward and backward to the image, on a random image pair of --size pixels. Prints
the median milliseconds of each form (the two alternate, round by round), their ratio, and
how far the folded form's distance and image gradient are from the unfolded one's
(`perceptual._FoldedFirstSlice`, docs/training_profile.md).
"""

from __future__ import annotations

import argparse
import statistics
import time


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--rounds", type=int, default=15)
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)

    import torch

    from archhead_addon.train.perceptual import ShiftTolerantLPIPS, unfolded

    torch.set_num_threads(args.threads)
    forms = {"folded": ShiftTolerantLPIPS()}
    forms["unfolded"] = unfolded(forms["folded"])
    rng = torch.Generator().manual_seed(0)
    image = torch.rand(1, 3, args.size, args.size, generator=rng)
    target = torch.rand(1, 3, args.size, args.size, generator=rng)

    def term(lpips) -> tuple[float, float, torch.Tensor]:
        x = image.clone().requires_grad_(True)
        start = time.perf_counter()
        distance = lpips.compare(x, lpips.reference(target)).sum()
        distance.backward()
        return 1e3 * (time.perf_counter() - start), float(distance.detach()), x.grad

    times: dict[str, list[float]] = {name: [] for name in forms}
    results = {}
    for _ in range(args.rounds):
        for name, lpips in forms.items():
            ms, distance, grad = term(lpips)
            times[name].append(ms)
            results[name] = distance, grad
    median = {name: statistics.median(t) for name, t in times.items()}
    pairs = zip(times["unfolded"], times["folded"], strict=True)
    ratio = statistics.median(u / f for u, f in pairs)
    (d_f, g_f), (d_u, g_u) = results["folded"], results["unfolded"]
    print(
        f"ST-LPIPS at {args.size}², {args.threads} threads, {args.rounds} rounds: "
        f"unfolded {median['unfolded']:.1f} ms, folded {median['folded']:.1f} ms, "
        f"{ratio:.2f}x (median of the per-round ratios); distance {d_f:.6f} against "
        f"{d_u:.6f}, image gradient max difference {float((g_f - g_u).abs().max()):.1e} "
        f"(largest entry {float(g_u.abs().max()):.1e})"
    )


if __name__ == "__main__":
    main()
