"""The masks' rasterizer in numpy, as it was before the kernel's library took it over
(`kernel.rasterize_mesh`), for tests and the benchmark only: the reference that
`train.parts_mask.rasterize` must match bit for bit (tests/test_mesh_raster.py,
benchmarks/tracking_changes.py). Vectorised over faces and the pixels of their bounding
boxes.
"""

from __future__ import annotations

import numpy as np

from ..train.parts_mask import NEAR

_MAX_PAIRS = 1 << 22  # (face, pixel) candidates per batch, bounds the memory (~200 MB)


def rasterize(
    points: np.ndarray, faces: np.ndarray, K: np.ndarray, w2c: np.ndarray, size: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """The nearest face at each pixel centre: its index (H,W) int64, -1 where no face is, and
    the perspective-correct barycentrics of the centre in it (H,W,3) float64 (0 where none).

    `points` (V,3) world, `K` (3,3) pixels, `w2c` (4,4) OpenCV, `size` (H, W)."""
    height, width = size
    cam = points @ w2c[:3, :3].T + w2c[:3, 3]
    z = cam[:, 2]
    xy = (cam @ K.T)[:, :2] / np.where(z > NEAR, z, 1.0)[:, None]
    keep = np.flatnonzero((z[faces] > NEAR).all(axis=1))
    tri = xy[faces[keep]]  # (F,3,2)
    # Pixel (i, j) has its centre at (j + 0.5, i + 0.5): the columns covered by [x0, x1]
    # are ceil(x0 - 0.5) .. floor(x1 - 0.5).
    lo = np.maximum(np.ceil(tri.min(axis=1) - 0.5), 0).astype(np.int64)
    hi = np.minimum(np.floor(tri.max(axis=1) - 0.5), [width - 1, height - 1]).astype(np.int64)
    extent = np.maximum(hi - lo + 1, 0)
    counts = extent[:, 0] * extent[:, 1]
    depth = np.full(height * width, -np.inf)  # 1/z of the nearest face so far
    face_at = np.full(height * width, -1, dtype=np.int64)
    bary = np.zeros((height * width, 3))
    bounds = np.concatenate([[0], np.cumsum(counts)])
    start = 0
    while start < len(keep):
        stop = max(int(np.searchsorted(bounds, bounds[start] + _MAX_PAIRS, "right")) - 1, start + 1)
        _rasterize_batch(
            slice(start, stop),
            keep,
            faces,
            tri,
            z,
            lo,
            extent,
            counts,
            width,
            (depth, face_at, bary),
        )
        start = stop
    return face_at.reshape(height, width), bary.reshape(height, width, 3)


def _rasterize_batch(batch, keep, faces, tri, z, lo, extent, counts, width, buffers):
    """Candidate pixels of faces[keep[batch]]: inside test, depth, z-buffer update."""
    n = counts[batch]
    if n.sum() == 0:
        return
    owner = np.repeat(np.arange(batch.start, batch.stop), n)
    local = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    col = lo[owner, 0] + local % extent[owner, 0]
    row = lo[owner, 1] + local // extent[owner, 0]
    p = np.stack([col + 0.5, row + 0.5], axis=1)
    a, b, c = tri[owner, 0], tri[owner, 1], tri[owner, 2]

    def edge(u, v, q):  # twice the signed area of (u, v, q)
        return (v[:, 0] - u[:, 0]) * (q[:, 1] - u[:, 1]) - (v[:, 1] - u[:, 1]) * (q[:, 0] - u[:, 0])

    area = edge(a, b, c)
    w = np.stack([edge(b, c, p), edge(c, a, p), edge(a, b, p)], axis=1)
    w = w / np.where(area == 0, 1.0, area)[:, None]
    inside = (area != 0) & (w >= 0).all(axis=1)
    owner, w, pixel = owner[inside], w[inside], (row * width + col)[inside]
    w_over_z = w / z[faces[keep[owner]]]  # screen-space linear, unlike w itself
    inv_z = w_over_z.sum(axis=1)
    order = np.lexsort((-inv_z, pixel))  # per pixel, nearest first
    pixel, first = np.unique(pixel[order], return_index=True)
    best = order[first]
    depth, face_at, bary = buffers
    closer = inv_z[best] > depth[pixel]
    pixel, best = pixel[closer], best[closer]
    depth[pixel] = inv_z[best]
    face_at[pixel] = keep[owner[best]]
    bary[pixel] = w_over_z[best] / inv_z[best, None]
