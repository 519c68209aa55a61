"""How many of a step's lanes can be used, per step geometry:
`python benchmarks/splat_fill.py [--gaussians N] [--size S]`.

The share of the vector limit that `splat_versions.py` prints is (lanes used / evaluated) x
(evaluated rate / limit), so the first factor bounds it. This replays the face scene's
compositing in numpy (the kernel's projection, its alpha test, front to back per 32-pixel
tile with its early stop) and counts, for each geometry, the lanes of an oracle that takes
only the steps holding a lane that composites a sample: blocks of C x R pixels in bands from
the entry's first such row (as the kernel's bands start at its first row), one block to a
step or k of the entry's blocks packed into one step of 16 lanes. The kernel's own steps
also take blocks its ellipse reaches without compositing there, so it evaluates more than
its geometry's oracle.
"""

from __future__ import annotations

import argparse

import numpy as np

from archhead_addon.splat import kernel, scenes
from archhead_addon.splat.reference import ALPHA_MAX, ALPHA_MIN, TRANSMITTANCE_MIN

TILE = 32  # the AVX-512 path's tile
# name: block columns, rows, blocks packed into one step (a step of C R k lanes)
GEOMETRIES = {
    "4 x 4 (AVX-512 step)": (4, 4, 1),
    "8 x 2": (8, 2, 1),
    "4 x 2 (AVX2 step)": (4, 2, 1),
    "4 x 1 (baseline step)": (4, 1, 1),
    "4 x 2 blocks, 2 to a step": (4, 2, 2),
    "4 x 1 rows, 4 to a step": (4, 1, 4),
    "2 x 2 quads, 4 to a step": (2, 2, 4),
    "single pixels, 16 to a step": (1, 1, 16),
}


def samples(scene: scenes.Scene) -> dict[int, list]:
    """Per tile, its entries front to back: (pixel rows, pixel columns, alpha) where the
    alpha test passes."""
    p = kernel.project(scene.gaussians.checked(), scene.settings(num_threads=1))
    tiles: dict[int, list] = {}
    w, h = scene.width, scene.height
    for i in np.argsort(p.depths, kind="stable"):
        rx, ry = p.radii[i]
        if rx <= 0:
            continue
        mx, my = p.means2d[i]
        x0, x1 = max(0, int(mx - rx)), min(w - 1, int(mx + rx))
        y0, y1 = max(0, int(my - ry)), min(h - 1, int(my + ry))
        if x0 > x1 or y0 > y1:
            continue
        a, b, c = p.conics[i].astype(np.float64)
        dx = mx - (np.arange(x0, x1 + 1) + 0.5)[None, :]
        dy = my - (np.arange(y0, y1 + 1) + 0.5)[:, None]
        power = -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy
        alpha = np.minimum(p.opacities[i] * np.exp(power), ALPHA_MAX)
        ys, xs = np.nonzero((power <= 0) & (alpha >= ALPHA_MIN))
        if not len(ys):
            continue
        al = alpha[ys, xs]
        ys, xs = ys + y0, xs + x0
        tile = (ys // TILE) * (w // TILE + 1) + xs // TILE
        for t in np.unique(tile):
            k = tile == t
            tiles.setdefault(int(t), []).append((ys[k] % TILE, xs[k] % TILE, al[k]))
    return tiles


def cells(col: np.ndarray, row: np.ndarray) -> int:
    """The number of distinct (column, row) cells of a tile."""
    return len(np.unique(row * TILE + col))


def lane_counts(tiles: dict[int, list]) -> tuple[int, dict[str, int]]:
    """Lanes used, and lanes evaluated per geometry's oracle."""
    used, evaluated = 0, dict.fromkeys(GEOMETRIES, 0)
    for entries in tiles.values():
        T = np.ones((TILE, TILE))
        for ys, xs, alpha in entries:
            t = T[ys, xs]
            new_t = t * (1 - alpha)
            use = (t > 0) & (new_t >= TRANSMITTANCE_MIN)  # T = 0: the pixel stopped
            T[ys, xs] = np.where(use, new_t, np.where(new_t < TRANSMITTANCE_MIN, 0.0, t))
            if not use.any():
                continue
            ys, xs = ys[use], xs[use]
            used += len(ys)
            for name, (C, R, k) in GEOMETRIES.items():
                blocks = cells(xs // C, (ys - ys.min()) // R)
                evaluated[name] += C * R * k * -(-blocks // k)
    return used, evaluated


def fill_table(scene: scenes.Scene) -> str:
    used, evaluated = lane_counts(samples(scene))
    lines = ["| oracle's steps | lanes evaluated | used / evaluated |", "|---|---:|---:|"]
    for name, n in evaluated.items():
        lines.append(f"| {name} | {n:,} | {used / n:.0%} |")
    return "\n".join([f"Lanes used (all geometries): {used:,}.", "", *lines])


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gaussians", type=int, default=60_000)
    parser.add_argument("--size", type=int, default=512, help="image side")
    args = parser.parse_args(argv)
    print(f"face_scene({args.gaussians:,}) at {args.size}²\n")
    print(fill_table(scenes.face_scene(args.gaussians, args.size, args.size, seed=0)))


if __name__ == "__main__":
    main()
