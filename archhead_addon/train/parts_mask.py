"""The eye/mouth parts mask B of the paper (eq. 6), made from the model's part labels.

The posed mesh is rasterized with a z-buffer (the splat kernel's library: pixel centres at
+0.5, perspective-correct depth and barycentrics).
At each pixel the nearest face's vertex labels (1 for eye or mouth in `vertex_parts`, else 0)
are interpolated with the barycentrics, and the pixel is in B where that exceeds 0.5: the
boundary follows the labels smoothly across the mesh's long thin triangles instead of
zig-zagging along their edges. Occlusion is exact at pixel centres: the far eye of a turned
head, or the mouth of a head seen from behind, is not in B.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..flame.model import PART_OTHER, FlameModel
from ..flame.regions import face_faces, head_faces
from ..splat.kernel import rasterize_mesh

NEAR = 1e-4  # metres; faces with a vertex closer to the camera plane are skipped


def rasterize(
    points: np.ndarray, faces: np.ndarray, K: np.ndarray, w2c: np.ndarray, size: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """The nearest face at each pixel centre: its index (H,W) int64, -1 where no face is, and
    the perspective-correct barycentrics of the centre in it (H,W,3) float64 (0 where none).

    `points` (V,3) world, `K` (3,3) pixels, `w2c` (4,4) OpenCV, `size` (H, W). The z-buffer
    runs in the splat kernel's library (`kernel.rasterize_mesh`)."""
    cam = points @ w2c[:3, :3].T + w2c[:3, 3]
    z = cam[:, 2]
    xy = (cam @ K.T)[:, :2] / np.where(z > NEAR, z, 1.0)[:, None]
    keep = np.flatnonzero((z[faces] > NEAR).all(axis=1))
    face_at, bary = rasterize_mesh(xy, z, faces[keep], size)
    hit = face_at >= 0
    face_at[hit] = keep[face_at[hit]]
    return face_at, bary


def parts_mask(
    model: FlameModel, vertices: np.ndarray, K: np.ndarray, w2c: np.ndarray, size: tuple[int, int]
) -> np.ndarray:
    """B (H,W) float32: 1 where the visible surface is eye or mouth, else 0.

    `vertices` (V,3) posed (FLAME forward of `model`). A model without labels gives zeros."""
    return surface_regions(model, vertices, K, w2c, size).parts


@dataclass(frozen=True)
class SurfaceRegions:
    """What the posed mesh covers at each pixel centre, (H,W) float32 each in {0, 1}."""

    parts: np.ndarray  # the eye/mouth mask B
    head: np.ndarray  # the head without its neck (flame.regions)
    mesh: np.ndarray  # the whole mesh, head and neck
    face: np.ndarray  # the face, the head's front below its forehead (flame.regions)


def surface_regions(
    model: FlameModel, vertices: np.ndarray, K: np.ndarray, w2c: np.ndarray, size: tuple[int, int]
) -> SurfaceRegions:
    """B, the head, the whole mesh and the face from one rasterization (occlusion exact at
    centres)."""
    face_at, bary = rasterize(
        np.asarray(vertices, np.float64),
        model.faces,
        np.asarray(K, np.float64),
        np.asarray(w2c, np.float64),
        size,
    )
    hit = face_at >= 0
    nearest = np.maximum(face_at, 0)
    if model.vertex_parts is None:
        parts = np.zeros(size, bool)
    else:
        labelled = (model.vertex_parts != PART_OTHER)[model.faces[nearest]]
        parts = ((bary * labelled).sum(axis=-1) > 0.5) & hit
    head = head_faces(model)[nearest] & hit
    face = face_faces(model)[nearest] & hit
    return SurfaceRegions(*(m.astype(np.float32) for m in (parts, head, hit, face)))
