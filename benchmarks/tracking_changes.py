"""What the tracker's speed-ups are worth, each against its form before, in one process, on a
tracked folder's own codes:

    python benchmarks/tracking_changes.py --data out/real_hn [--frames 40] [--repeat 3]

- "masks" (2026-11-28): a frame's head-and-neck region at the folder's size, the mesh
  rasterized by the numpy z-buffer ("before", `splat/mesh_reference.py`) and by the splat
  kernel's library ("after", `kernel.rasterize_mesh`); the regions must be identical.
- "refine points": one pass of the photometric step's points and normals over the clip's
  frames, forward, and backward through the points (the refinement takes no gradient
  through the normals), as `FacePoints.place` placed them before 2026-11-28 (every
  point a gather of three corners times barycentrics, (T,P,3,3)), then (the vertices
  themselves, the triangles' centres from three gathers) and now (the centres a sparse
  product, the normals without a gradient: they only weight the points); all must agree
  to round-off.
- "landmark fit step" and "refine pose" (2026-11-30): the landmark energy over the clip's
  frames (`ClipFit.energy`), and the refinement's posing of its region vertices, forward
  and backward, with FLAME's skinning and the landmarks' barycentric mix as they were
  (`FlameLayer` blending each vertex's rotation and translation apart, the landmarks three
  gathered corners each) and as they are (one (3,4) transform a vertex applied in
  homogeneous coordinates, the landmarks a sparse product); the values must agree to
  round-off.

The refinement's third saving of 2026-11-28, its 30 colour-only steps observing the fixed
fit once instead of posing and sampling every step, is counted, not timed: it leaves 100 of
130 steps posing. Prints milliseconds (the best of `--repeat`) and the ratios.
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


def place_three_gathers(points, verts):
    """`FacePoints.place` of 2026-11-28 to 2026-11-30: the centres from three gathers."""
    import torch

    a, b, c = (verts[:, points.faces[:, k]] for k in range(3))
    return torch.cat([verts, (a + b + c) / 3], dim=1), points.normals(verts)


def skin_apart(layer, transforms, v_posed):
    """FLAME's skinning before 2026-11-30: each vertex's blended (3,3) rotation and its
    translation apart."""
    import torch

    blend = torch.einsum("vj,bjrc->bvrc", layer.weights, transforms[:, :, :3, :])
    return torch.einsum("bvrc,bvc->bvr", blend[..., :3], v_posed) + blend[..., 3]


def landmarks_gathered(fit, corners, bary):
    """`ClipFit.project` before 2026-11-30: each landmark three gathered corners."""
    verts = fit.pose(fit.layer, fit.landmark_vertices)
    pts = (verts[:, corners] * bary[None, :, :, None]).sum(2)
    height, width = fit.size
    return fit.project_points(pts, fit.focal(), (width / 2, height / 2))


def skinning_rows(model, emb, points, track, repeat: int) -> list[tuple]:
    """The landmark fit's energy and the refinement's posing over every frame, forward and
    backward, with the skinning and landmarks before 2026-11-30 and now."""
    import torch

    from archhead_addon.flame.lbs_torch import FlameLayer
    from archhead_addon.track.fit import ClipFit

    codes = {k: track[k] for k in PER_FRAME} | {"shape": track["shape"][0]}
    frames = len(track["expr"])
    fit = ClipFit(model, emb, np.zeros((frames, len(emb.bary), 2)), track["frame_ids"],
                  float(track["fps"]), tuple(int(x) for x in track["image_size"][::-1]),
                  init=codes)  # fmt: skip
    corners = np.unique(model.faces[emb.faces], return_inverse=True)[1].reshape(-1, 3)
    corners, bary = torch.from_numpy(corners), torch.from_numpy(emb.bary.astype(np.float32))
    now_skin, now_project = FlameLayer._skin, ClipFit.project
    forms = {
        "before": (skin_apart, lambda self: landmarks_gathered(self, corners, bary)),
        "after": (now_skin, now_project),
    }
    rows, values = [], {}
    for part in ("landmark fit step", "refine pose"):
        for name, (skin, project) in forms.items():
            FlameLayer._skin, ClipFit.project = skin, project

            def one_pass(part=part, name=name):
                for p in fit.p.values():
                    p.grad = None
                if part == "landmark fit step":
                    out = fit.energy()[0]
                else:
                    out = fit.pose(points.layer, points.ids)
                out.sum().backward()
                values[part, name] = (out.detach(), fit.p["expr"].grad.clone())

            try:
                rows.append((part, name, best_ms(one_pass, repeat)))
            finally:
                FlameLayer._skin, ClipFit.project = now_skin, now_project
        for before, after in zip(values[part, "before"], values[part, "after"], strict=True):
            torch.testing.assert_close(before, after, rtol=1e-4, atol=1e-5)
    return rows


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

    emb = landmark_embedding(model)
    points = FacePoints(model, emb)
    all_codes = {k: track[k] for k in PER_FRAME} | {"shape": track["shape"][0]}
    verts = torch.from_numpy(forward(model, **all_codes)[:, points.ids]).float()
    placed = {}

    def one_pass(name, place):
        v = verts.clone().requires_grad_(True)
        at, normals = place(v)
        at.sum().backward()  # the refinement takes no gradient through the normals
        placed[name] = (at.detach(), normals.detach())

    forms = (
        ("before", lambda v: place_before(points, v)),
        ("three gathers", lambda v: place_three_gathers(points, v)),
        ("after", points.place),
    )
    for name, place in forms:
        rows.append(
            ("refine points", name, best_ms(lambda n=name, f=place: one_pass(n, f), args.repeat))
        )
    for name in ("three gathers", "after"):
        for before, after in zip(placed["before"], placed[name], strict=True):
            torch.testing.assert_close(before, after, rtol=1e-4, atol=1e-5)
    rows += skinning_rows(model, emb, points, track, args.repeat)

    print(
        f"# Tracking changes: {args.data}, {size[1]}x{size[0]} px; masks over {n} frames, the "
        f"refinement's points ({len(points)}), the landmark fit and the refinement's posing "
        f"over all {len(verts)} frames; "
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
