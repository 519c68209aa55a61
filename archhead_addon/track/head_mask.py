"""The head-and-neck mask of a tracked frame: the person, cut to what FLAME can carry.

The person segmentation keeps shoulders, shirt and hair down the back, none of which the
FLAME mesh reaches; the comparable methods' data (the INSTA protocol) keeps only head and
neck, and so does this mask: the person segmentation times a region made of
- the tracked mesh's outline (head and neck, down to where FLAME's neck ends), widened by
  NECK_MARGIN against the tracking's error;
- hair: pixels within HAIR_REACH of the head's outline (without the neck) and no lower than
  the head's lowest row, so hair above and beside the head stays and hair on the shoulders
  goes.
Both reaches are fractions of the head's projected height, so the mask is the same at any
frame size and distance.
"""

from __future__ import annotations

import numpy as np

from ..flame.lbs import forward
from ..flame.model import FlameModel
from ..train.parts_mask import surface_regions

HAIR_REACH = 0.25  # of the head's height (crown to chin): hair volume beyond the skull
NECK_MARGIN = 0.03  # of the head's height
PER_FRAME = ("expr", "jaw", "neck", "eyes", "rotation", "translation")


def _within(outline: np.ndarray, reach: float) -> np.ndarray:
    """(H,W) bool: pixels at most `reach` pixels from a pixel of `outline` (bool)."""
    import cv2

    if reach < 0.5:
        return outline.copy()
    distance = cv2.distanceTransform((~outline).astype(np.uint8), cv2.DIST_L2, 5)
    return distance <= reach


def region(head: np.ndarray, mesh: np.ndarray) -> np.ndarray:
    """(H,W) bool: the head-and-neck region from the rasterized head (without neck) and
    whole mesh, both (H,W) in {0, 1} (`train.parts_mask.surface_regions`)."""
    head, mesh = head > 0.5, mesh > 0.5
    rows = np.flatnonzero(head.any(axis=1))
    if rows.size == 0:  # the head is out of view: at most the neck's outline
        return mesh
    height = rows[-1] - rows[0] + 1
    hair = _within(head, HAIR_REACH * height)
    hair[rows[-1] + 1 :] = False
    neck = _within(mesh, NECK_MARGIN * height)
    mesh_rows = np.flatnonzero(mesh.any(axis=1))
    neck[mesh_rows[-1] + 1 :] = False  # below where FLAME's neck ends
    return hair | neck


def head_and_neck_masks(
    model: FlameModel,
    codes: dict,
    K: np.ndarray,
    w2c: np.ndarray,
    size: tuple[int, int],
    chunk: int = 32,
):
    """Yield each frame's region (H,W) bool in order; `codes` as the fit holds them
    (shape and static_offset once, the rest (T,n)), one camera for the clip."""
    once = {k: codes[k] for k in ("shape", "static_offset") if codes.get(k) is not None}
    n = len(codes["expr"])
    for start in range(0, n, chunk):
        part = {k: codes[k][start : start + chunk] for k in PER_FRAME}
        for vertices in forward(model, **once, **part):
            found = surface_regions(model, vertices, K, w2c, size)
            yield region(found.head, found.mesh)
