"""ST-LPIPS over a stage-2 step's renders: one pass per render against one batched pass.

    python benchmarks/perceptual_batch.py [--size 256] [--renders 3] [--rounds 8] [--threads 2]
        [--device cpu]

The step's renders share their frame's reference; each variant computes the term of every
render, forward and backward to the images: `compare` once per render (what training does),
or once on the renders stacked into one batch, the reference's features broadcast over it.
The two alternate, round by round; prints their median milliseconds and the largest gap
between their image gradients (docs/gpu.md: whether batching pays on this device).
"""

from __future__ import annotations

import argparse
import statistics
import time


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--renders", type=int, default=3)
    p.add_argument("--rounds", type=int, default=8)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--device", default="cpu", help="cpu or cuda")
    args = p.parse_args(argv)

    import torch

    from archhead_addon.train.perceptual import Reference, ShiftTolerantLPIPS

    torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    # a GPU runs asynchronously: each timing waits for its kernels
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    lpips = ShiftTolerantLPIPS().to(device)
    gen = torch.Generator().manual_seed(0)
    n, size = args.renders, args.size
    reference = lpips.reference(torch.rand(1, 3, size, size, generator=gen).to(device))
    images = torch.rand(n, 3, size, size, generator=gen).to(device)

    def separate():
        grads = []
        for k in range(n):
            x = images[k : k + 1].clone().requires_grad_()
            lpips.compare(x, reference).sum().backward()
            grads.append(x.grad)
        return torch.cat(grads)

    def batched():
        x = images.clone().requires_grad_()
        shared = Reference(tuple(x.shape), [f.expand(n, -1, -1, -1) for f in reference.features])
        lpips.compare(x, shared).sum().backward()
        return x.grad

    times = {"separate": [], "batched": []}
    grads = {}
    for _ in range(args.rounds):
        for name, fn in (("separate", separate), ("batched", batched)):
            sync()
            start = time.perf_counter()
            grads[name] = fn()
            sync()
            times[name].append(1e3 * (time.perf_counter() - start))
    gap = float((grads["separate"] - grads["batched"]).abs().max())
    where = f"{args.threads} threads" if device.type == "cpu" else str(device)
    print(f"ST-LPIPS of {n} renders at {size}², {where}, {args.rounds} rounds:")
    for name, values in times.items():
        print(f"  {name}: {statistics.median(values):.1f} ms (median)")
    ratio = statistics.median(times["separate"]) / statistics.median(times["batched"])
    print(f"  batched speed-up: {ratio:.2f}x; largest image-gradient gap {gap:.2e}")


if __name__ == "__main__":
    main()
