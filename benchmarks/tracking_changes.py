"""What the tracker's two speed-ups of 2026-11-28 are worth, each against its form before, in
one process, on a tracked folder's own codes:

    python benchmarks/tracking_changes.py --data out/real_hn [--frames 40] [--repeat 3]

- "masks": a frame's head-and-neck region at the folder's size, the mesh rasterized by the
  numpy z-buffer ("before", `splat/mesh_reference.py`) and by the splat kernel's
  library ("after", `kernel.rasterize_mesh`); the regions must be identical.
- "refine points": one pass of the photometric step's points and normals over the clip's
  frames, forward and backward, as `FacePoints.place` placed them before (every point a
  gather of three corners times barycentrics, (T,P,3,3)) and as it does now (the vertices
  themselves, the triangles' centres from three gathers); the two must agree to round-off.

The refinement's third saving, its 30 colour-only steps observing the fixed fit once instead
of posing and sampling every step, is counted, not timed: it leaves 100 of 130 steps posing.
Prints milliseconds (the best of `--repeat`) and the ratios.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

PER_FRAME = ("expr", "jaw", "neck", "eyes", "rotation", "translation")


def best_ms(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(1e3 * (time.perf_counter() - start))
    return min(times)


def place_before(points, verts):
    """`FacePoints.place` as it was: each point a barycentric mix of three corners."""
    import torch

    faces = points.faces
    a, b, c = (verts[:, faces[:, k]] for k in range(3))
    face_n = torch.linalg.cross(b - a, c - a)
    n = torch.zeros_like(verts)
    for k in range(3):
        n.index_add_(1, faces[:, k], face_n)
    own = torch.arange(len(points.ids))[:, None]
    corners = torch.cat([own.repeat(1, 3), faces])
    bary = torch.cat(
        [torch.tensor([[1.0, 0, 0]]).repeat(len(own), 1), torch.full(faces.shape, 1 / 3)]
    )

    def mix(x):
        return (x[:, corners] * bary[None, :, :, None]).sum(2)

    normals = mix(n)
    return mix(verts), normals / normals.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, required=True, help="a tracked folder (tracking.npz)")
    p.add_argument("--frames", type=int, default=40, help="frames whose masks are timed")
    p.add_argument("--repeat", type=int, default=3, help="timings of each; the best is kept")
    args = p.parse_args(argv)
    import torch

    import archhead_addon.train.parts_mask as parts_mask
    from archhead_addon.flame import load_model
    from archhead_addon.flame.lbs import forward
    from archhead_addon.splat.mesh_reference import rasterize as numpy_rasterize
    from archhead_addon.track.embedding import landmark_embedding
    from archhead_addon.track.head_mask import head_and_neck_masks
    from archhead_addon.track.photometric import FacePoints

    track = np.load(args.data / "tracking.npz")
    model = load_model()
    size = tuple(int(x) for x in track["image_size"][::-1])
    n = min(args.frames, len(track["expr"]))
    codes = {k: track[k][:n] for k in PER_FRAME} | {"shape": track["shape"][0]}
    K, w2c = track["K"][0], track["w2c"][0]

    kernel_rasterize = parts_mask.rasterize
    regions = {}

    def masks(name, rasterize):
        parts_mask.rasterize = rasterize
        regions[name] = list(head_and_neck_masks(model, codes, K, w2c, size))

    rows = []
    for name, fn in (("before", numpy_rasterize), ("after", kernel_rasterize)):
        rows.append(
            ("masks", name, best_ms(lambda fn=fn, name=name: masks(name, fn), args.repeat) / n)
        )
    parts_mask.rasterize = kernel_rasterize
    assert all(
        np.array_equal(a, b) for a, b in zip(regions["before"], regions["after"], strict=True)
    )

    points = FacePoints(model, landmark_embedding(model))
    all_codes = {k: track[k] for k in PER_FRAME} | {"shape": track["shape"][0]}
    verts = torch.from_numpy(forward(model, **all_codes)[:, points.ids]).float()
    placed = {}

    def one_pass(name, place):
        v = verts.clone().requires_grad_(True)
        at, normals = place(v)
        (at.sum() + normals.sum()).backward()
        placed[name] = (at.detach(), normals.detach())

    for name, place in (("before", lambda v: place_before(points, v)), ("after", points.place)):
        rows.append(
            ("refine points", name, best_ms(lambda n=name, f=place: one_pass(n, f), args.repeat))
        )
    for before, after in zip(placed["before"], placed["after"], strict=True):
        torch.testing.assert_close(before, after, rtol=1e-4, atol=1e-5)

    print(
        f"# Tracking changes: {args.data}, {size[1]}x{size[0]} px; masks over {n} frames, the "
        f"refinement's points ({len(points)}) over all {len(verts)} frames; "
        f"{torch.get_num_threads()} threads, best of {args.repeat}\n"
    )
    print("| part | version | ms | speed-up over before |")
    print("|---|---|---:|---:|")
    first = {}
    for part, name, ms in rows:
        first.setdefault(part, ms)
        print(f"| {part} | {name} | {ms:.1f} | {first[part] / ms:.2f}x |")


if __name__ == "__main__":
    main()
