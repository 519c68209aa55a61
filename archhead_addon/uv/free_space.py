"""Finding room in a UV layout for new islands (teeth) without touching existing ones."""

from __future__ import annotations

import numpy as np


def coverage_grid(uv: np.ndarray, uv_faces: np.ndarray, size: int = 256, margin: int = 2):
    """Boolean (size,size) grid, row = v, col = u: True where any UV triangle lies (dilated)."""
    grid = np.zeros((size, size), dtype=bool)
    tri = uv[uv_faces] * size  # (F,3,2) in cell units
    lo = np.clip(np.floor(tri.min(1)).astype(int), 0, size - 1)
    hi = np.clip(np.ceil(tri.max(1)).astype(int), 0, size - 1)
    # conservative: a cell counts as used when the triangle's bounding box touches it, which
    # over-covers long thin triangles slightly but never misses one
    for (u0, v0), (u1, v1) in zip(lo, hi, strict=True):
        grid[v0 : v1 + 1, u0 : u1 + 1] = True
    if margin:
        used = np.argwhere(grid)
        for dv in range(-margin, margin + 1):
            for du in range(-margin, margin + 1):
                idx = np.clip(used + (dv, du), 0, size - 1)
                grid[idx[:, 0], idx[:, 1]] = True
    return grid


def largest_empty_rectangle(grid: np.ndarray) -> tuple[int, int, int, int]:
    """(row0, col0, rows, cols) of the largest all-False rectangle (histogram method)."""
    n_rows, n_cols = grid.shape
    heights = np.zeros(n_cols, dtype=int)
    best = (0, 0, 0, 0)
    for r in range(n_rows):
        heights = np.where(grid[r], 0, heights + 1)
        stack: list[int] = []
        for c in range(n_cols + 1):
            h = heights[c] if c < n_cols else 0
            while stack and heights[stack[-1]] >= h:
                top = stack.pop()
                left = stack[-1] + 1 if stack else 0
                area = heights[top] * (c - left)
                if area > best[2] * best[3]:
                    best = (r - heights[top] + 1, left, int(heights[top]), c - left)
            stack.append(c)
    return best


def free_uv_box(uv: np.ndarray, uv_faces: np.ndarray, size: int = 256):
    """(u0, v0, u1, v1) of the largest empty region of the layout, in UV units."""
    r0, c0, rows, cols = largest_empty_rectangle(coverage_grid(uv, uv_faces, size))
    if rows * cols == 0:
        raise ValueError("the UV layout has no free space for new islands")
    return c0 / size, r0 / size, (c0 + cols) / size, (r0 + rows) / size
