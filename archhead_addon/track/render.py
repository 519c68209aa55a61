"""A plain numpy render of a posed FLAME mesh: the model's albedo (or grey) with diffuse
shading from smooth normals. Used to find landmarks on a model and to draw overlays."""

from __future__ import annotations

import numpy as np

from ..flame.model import FlameModel
from ..train.parts_mask import rasterize

GREY = np.array([0.72, 0.62, 0.56])  # a skin-like grey for models without an albedo


def vertex_normals(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    tri = verts[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # area-weighted
    out = np.zeros_like(verts)
    for k in range(3):
        np.add.at(out, faces[:, k], n)
    return out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-12)


def render_mesh(
    model: FlameModel, verts: np.ndarray, K: np.ndarray, w2c: np.ndarray, size: tuple[int, int]
):
    """(RGB (H,W,3) float in [0,1], coverage (H,W) bool, face index (H,W), barycentrics)."""
    face_at, bary = rasterize(verts, model.faces, K, w2c, size)
    hit = face_at >= 0
    f = model.faces[np.maximum(face_at, 0)]  # (H,W,3)
    if model.albedo is not None and model.uv is not None:
        uv = (bary[..., None] * model.uv[model.uv_faces[np.maximum(face_at, 0)]]).sum(-2)
        h, w = model.albedo.shape[:2]
        x = np.clip((uv[..., 0] * w).astype(np.int64), 0, w - 1)
        y = np.clip(((1 - uv[..., 1]) * h).astype(np.int64), 0, h - 1)
        colour = model.albedo[y, x, :3] / 255.0
    else:
        colour = np.broadcast_to(GREY, (*size, 3))
    normals = vertex_normals(verts, model.faces) @ w2c[:3, :3].T
    n = (bary[..., None] * normals[f]).sum(-2)
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    shade = 0.3 + 0.7 * np.clip(-n[..., 2], 0, 1)  # light from the camera
    return np.where(hit[..., None], colour * shade[..., None], 0.0), hit, face_at, bary
