"""Teeth behind the lips: an upper arch that follows the neck joint, a lower one the jaw.

Following GaussianAvatars' idea (the geometry and code here are our own): each arch is a
U-shaped slab built from the lip rings' rest positions, so the avatar has Gaussians to place
in the mouth. Teeth take the identity blendshapes of the lips (they follow head shape), no
expression or pose correctives, and a UV island in free space of the layout.
"""

from __future__ import annotations

import numpy as np

from ..uv.free_space import free_uv_box
from .model import PART_MOUTH, FlameModel

# FLAME 2020 / 2023 topology (5,023 vertices): the mouth opening's upper and lower edges,
# left corner to right corner (facts from the GaussianAvatars project).
FLAME_N_VERTS = 5023
FLAME_LIP_RING_UPPER = (
    1713,
    1715,
    1716,
    1735,
    1696,
    1694,
    1657,
    3543,
    2774,
    2811,
    2813,
    2850,
    2833,
    2832,
    2830,
)
FLAME_LIP_RING_LOWER = (
    1576,
    1577,
    1773,
    1774,
    1795,
    1802,
    1865,
    3503,
    2948,
    2905,
    2898,
    2881,
    2880,
    2713,
    2712,
)
UPPER_JOINT, LOWER_JOINT = 1, 2  # neck, jaw
TEETH_COLOUR = (236, 228, 210)  # ivory, painted into the albedo under the teeth island


def lip_rings(model: FlameModel):
    """(upper, lower) ring indices: the model's own, FLAME's for FLAME topology, else None."""
    if model.lip_ring_upper is not None and model.lip_ring_lower is not None:
        return model.lip_ring_upper, model.lip_ring_lower
    if model.n_verts == FLAME_N_VERTS:
        return np.array(FLAME_LIP_RING_UPPER), np.array(FLAME_LIP_RING_LOWER)
    return None


def _resample_ring(points: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """n points evenly spaced by arc length, plus the (index, weight) pairs that produce them."""
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    arc = np.concatenate([[0], np.cumsum(seg)])
    target = np.linspace(0, arc[-1], n)
    i = np.clip(np.searchsorted(arc, target, side="right") - 1, 0, len(points) - 2)
    t = (target - arc[i]) / np.maximum(seg[i], 1e-12)
    return i, t


def _arch_rows(upper: np.ndarray, lower: np.ndarray, sign: float) -> np.ndarray:
    """Four rows (front edge, front root, back root, back edge) of one arch, (4, n, 3).

    sign +1 builds the upper arch (roots go up), -1 the lower one.
    """
    middle = (upper + lower) / 2
    middle[:, 1] = middle[:, 1].mean()  # a level bite plane
    width = np.linalg.norm(middle[-1] - middle[0])
    centre_x = (middle[0, 0] + middle[-1, 0]) / 2
    s = (middle[:, 0] - centre_x) / (width / 2)  # -1 .. 1 across the mouth
    edge = middle.copy()
    edge[:, 0] = centre_x + 0.92 * (middle[:, 0] - centre_x)  # inside the cheeks
    edge[:, 2] -= width * (0.08 + 0.30 * s**2)  # behind the lips, curving back at the sides
    edge[:, 1] -= sign * 0.02 * width  # upper incisors overlap the lower ones slightly
    edge[:, 2] -= (sign < 0) * 0.03 * width
    height, thickness = 0.22 * width, 0.14 * width
    root = edge + np.array([0, sign * height, -0.15 * height])
    back = np.array([0, 0, -thickness])
    return np.stack([edge, root, root + back, edge + back])


def _strip_faces(n_rows: int, n_cols: int, offset: int) -> np.ndarray:
    """Triangles of a row-major grid of vertices starting at `offset`, one consistent winding."""
    r, c = np.meshgrid(np.arange(n_rows - 1), np.arange(n_cols - 1), indexing="ij")
    a = offset + r * n_cols + c
    b, d, e = a + 1, a + n_cols, a + n_cols + 1
    tris = np.concatenate([np.stack([a, b, e], -1), np.stack([a, e, d], -1)], axis=-1)
    return tris.reshape(-1, 3)


def add_teeth(model: FlameModel, columns: int = 24) -> FlameModel:
    """The model with teeth appended (new vertices and faces at the end); unchanged if the
    model declares no lip rings."""
    rings = lip_rings(model)
    if rings is None or model.extras.get("teeth"):
        return model
    upper_idx, lower_idx = (np.asarray(r) for r in rings)
    i, t = _resample_ring(model.v_template[upper_idx], columns)

    def along(values):  # values per ring vertex -> values per column
        return values[i] * (1 - t)[:, None] + values[i + 1] * t[:, None]

    upper, lower = along(model.v_template[upper_idx]), along(model.v_template[lower_idx])
    arches = [_arch_rows(upper, lower, +1.0), _arch_rows(upper, lower, -1.0)]
    n_old = model.n_verts
    per_arch = 4 * columns
    new_v = np.concatenate([a.reshape(-1, 3) for a in arches])
    faces = np.concatenate(
        [_strip_faces(4, columns, n_old), _strip_faces(4, columns, n_old + per_arch)]
    )
    faces = _orient_outward(faces, np.concatenate([model.v_template, new_v]), columns)

    lip_dirs = (
        model.shapedirs[upper_idx, :, : model.n_shape]
        + model.shapedirs[lower_idx, :, : model.n_shape]
    ) / 2
    teeth_dirs = np.zeros((2 * per_arch, 3, model.shapedirs.shape[2]))
    teeth_dirs[:, :, : model.n_shape] = np.tile(
        along(lip_dirs.reshape(len(upper_idx), -1)).reshape(columns, 3, -1), (8, 1, 1)
    )
    weights = np.zeros((2 * per_arch, model.weights.shape[1]))
    weights[:per_arch, UPPER_JOINT] = 1
    weights[per_arch:, LOWER_JOINT] = 1
    changes = dict(
        v_template=np.concatenate([model.v_template, new_v]),
        faces=np.concatenate([model.faces, faces]),
        shapedirs=np.concatenate([model.shapedirs, teeth_dirs]),
        posedirs=np.concatenate([model.posedirs, np.zeros((2 * per_arch, 3, 36))]),
        j_regressor=np.concatenate([model.j_regressor, np.zeros((5, 2 * per_arch))], axis=1),
        weights=np.concatenate([model.weights, weights]),
        model_id=f"{model.model_id}+teeth",
        extras={
            **model.extras,
            "teeth": {"first_vertex": n_old, "per_arch": per_arch, "first_face": len(model.faces)},
        },
    )
    if model.vertex_parts is not None:
        changes["vertex_parts"] = np.concatenate(
            [model.vertex_parts, np.full(2 * per_arch, PART_MOUTH, np.uint8)]
        )
    if model.uv is not None:
        changes.update(_teeth_uvs(model, columns, faces - n_old))
    return model.replace(**changes)


def _orient_outward(faces, verts, columns):
    """Flip an arch whose winding points into the slab; the grid is one folded surface, so
    its first (front) triangle decides for the whole arch."""
    out = faces.copy()
    per_strip = 2 * (columns - 1)
    for arch in range(2):
        block = slice(arch * 3 * per_strip, (arch + 1) * 3 * per_strip)
        tri = verts[out[block][0]]
        normal = np.cross(tri[1] - tri[0], tri[2] - tri[0])
        if normal[2] < 0:  # the front surface faces +z
            out[block] = out[block][:, ::-1]
    return out


def _teeth_uvs(model: FlameModel, columns: int, local_faces: np.ndarray) -> dict:
    """Two grid islands side by side in the largest free box; paints them in the albedo."""
    u0, v0, u1, v1 = free_uv_box(model.uv, model.uv_faces)
    pad_u, pad_v = 0.05 * (u1 - u0), 0.05 * (v1 - v0)
    u0, u1, v0, v1 = u0 + pad_u, u1 - pad_u, v0 + pad_v, v1 - pad_v
    half = (u1 - u0) / 2
    uvs = []
    for arch in range(2):
        us = np.linspace(
            u0 + arch * half + 0.05 * half, u0 + (arch + 1) * half - 0.05 * half, columns
        )
        vs = np.linspace(v0, v1, 4)
        uu, vv = np.meshgrid(us, vs)
        uvs.append(np.stack([uu, vv], -1).reshape(-1, 2))
    n_vt = len(model.uv)
    out = {
        "uv": np.concatenate([model.uv, *uvs]),
        "uv_faces": np.concatenate([model.uv_faces, local_faces + n_vt]),
    }
    if model.albedo is not None:
        albedo = model.albedo.copy()
        h, w = albedo.shape[:2]
        rows = slice(int((1 - v1) * h), int(np.ceil((1 - v0) * h)))  # image rows run down in v
        albedo[rows, int(u0 * w) : int(np.ceil(u1 * w))] = TEETH_COLOUR
        out["albedo"] = albedo
    return out
