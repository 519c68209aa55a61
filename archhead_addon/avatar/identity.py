"""An avatar's identity on its mesh: the FLAME identity code and, when the tracking fitted
one, a per-vertex static offset (metres, the base model's vertices; the teeth appended after
them do not move). FLAME adds the offset to the shaped template before posing, so applying it
to the template once is exact."""

from __future__ import annotations

import numpy as np

from ..flame.model import FlameModel


def offset_mesh(mesh: FlameModel, offset: np.ndarray | None) -> FlameModel:
    """The mesh with the identity offset (V_base,3) added to its template."""
    if offset is None:
        return mesh
    full = np.zeros_like(mesh.v_template)
    full[: len(offset)] = offset
    return mesh.replace(v_template=mesh.v_template + full)


def bake_identity(mesh: FlameModel, shape: np.ndarray, offset: np.ndarray | None) -> FlameModel:
    """The mesh with the whole identity applied to the template and the identity blendshapes
    dropped: FLAME computes the same vertices and joints from it, without the identity
    product per frame."""
    mesh = offset_mesh(mesh, offset)
    shaped = mesh.shapedirs[:, :, : len(shape)] @ shape.astype(np.float64)
    return mesh.replace(
        v_template=mesh.v_template + shaped,
        n_shape=0,
        shapedirs=mesh.shapedirs[:, :, mesh.n_shape :],
    )
