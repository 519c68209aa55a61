"""Splat kernel benchmark: `python benchmarks/splat_kernel.py [--quick] [--no-torch]`.

Face-like scenes (`scenes.face_scene`: Gaussians over a head-sized ellipsoid 0.6 m away,
about one texel across) at 3k / 18k / 46k Gaussians and 256^2 / 512^2. Prints a Markdown
table of forward and backward wall-clock milliseconds (best of several runs, so other load
on the machine inflates the figures as little as possible) for 1 and 2 kernel threads, and
the pure-torch tile renderer (`reference.render_tiles_torch`, 2 torch threads, best of 2) as
a ratio to the kernel on 2 threads.
"""

from __future__ import annotations

import argparse
import os
import platform
from functools import partial

import numpy as np

from archhead_addon.splat import kernel, scenes
from archhead_addon.timing import time_calls

SIZES = (3_000, 18_000, 46_000)
RESOLUTIONS = (256, 512)


def best_of(fn, repeats: int) -> float:
    return time_calls(fn, repeats).min_ms


def time_kernel(scene: scenes.Scene, threads: int, repeats: int):
    g = scene.gaussians.checked()
    settings = scene.settings(num_threads=threads)
    g_rgb = np.full((scene.height, scene.width, 3), 0.1, np.float32)
    ctx = kernel.forward(g, settings)[1]  # warm-up
    fwd = best_of(lambda: kernel.forward(g, settings), repeats)
    bwd = best_of(lambda: kernel.backward(ctx, g_rgb), repeats)
    return fwd, bwd, ctx.stats()


def time_torch_tiles(scene: scenes.Scene, repeats: int = 2):
    """Best forward and best backward ms of the pure-torch tile renderer (2 torch threads)."""
    import torch

    from archhead_addon.splat.reference import render_tiles_torch

    torch.set_num_threads(2)
    camera = (torch.tensor(scene.viewmat, dtype=torch.float32),
              torch.tensor(scene.K, dtype=torch.float32))  # fmt: skip
    times = [
        _forward_backward_ms(
            partial(
                render_tiles_torch,
                scene.gaussians.map(lambda a: torch.tensor(a, requires_grad=True)),
                *camera,
                scene.width,
                scene.height,
            )
        )
        for _ in range(repeats)
    ]
    return min(t[0] for t in times), min(t[1] for t in times)


def _forward_backward_ms(render) -> tuple[float, float]:
    """ms of one render() and of the backward pass of its graph."""
    image = []
    forward = time_calls(lambda: image.append(render()), 1).min_ms
    backward = time_calls(lambda: (image[0].rgb.sum() * 0.1).backward(), 1).min_ms
    return forward, backward


def run(sizes=SIZES, resolutions=RESOLUTIONS, repeats: int = 15, torch_tiles: bool = True):
    if torch_tiles:  # warm torch up outside the timings
        time_torch_tiles(scenes.face_scene(200, 32, 32), repeats=1)
    rows = []
    for n in sizes:
        for res in resolutions:
            scene = scenes.face_scene(n, res, res, seed=0)
            f1, b1, stats = time_kernel(scene, 1, repeats)
            f2, b2, _ = time_kernel(scene, 2, repeats)
            tf, tb = time_torch_tiles(scene) if torch_tiles else (float("nan"),) * 2
            rows.append((n, res, stats["intersections"], f1, b1, f2, b2, tf, tb))
            print(f"  {n} @ {res}^2 done", flush=True)
    return rows


def table(rows) -> str:
    head = (
        "| Gaussians | image | tile hits | fwd 1T | bwd 1T | fwd 2T | bwd 2T "
        "| torch tiles fwd | torch tiles bwd | speed-up fwd / bwd (2T) |"
    )
    lines = [head, "|" + "---|" * 10]
    for n, res, hits, f1, b1, f2, b2, tf, tb in rows:
        lines.append(
            f"| {n:,} | {res}² | {hits:,} | {f1:.1f} | {b1:.1f} | {f2:.1f} | {b2:.1f} "
            f"| {tf:,.0f} | {tb:,.0f} | {tf / f2:,.0f}× / {tb / b2:,.0f}× |"
        )
    return "\n".join(lines)


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(line.split(":", 1)[1].strip() for line in f if "model name" in line)
    except (OSError, StopIteration):
        pass
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    return f"{cpu}, {os.cpu_count()} cores, load average {load} at the end of the run"


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="3k and 18k at 256^2 only")
    parser.add_argument("--no-torch", action="store_true", help="skip the torch tile renderer")
    parser.add_argument("--repeats", type=int, default=15)
    args = parser.parse_args(argv)
    sizes, resolutions = ((3_000, 18_000), (256,)) if args.quick else (SIZES, RESOLUTIONS)
    rows = run(sizes, resolutions, args.repeats, not args.no_torch)
    print()
    print(f"Times in ms, best of {args.repeats} (kernel) / best of 2 (torch tiles).")
    print(machine())
    print()
    print(table(rows))


if __name__ == "__main__":
    main()
