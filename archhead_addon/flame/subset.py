"""A FLAME model reduced to some of its vertices, exact for those vertices.

Joints are regressed from the whole mesh, so the reduced model carries the five rest joints
as extra vertices (template and blendshape directions of J_regressor applied to the whole
mesh) and a regressor that picks them: its forward pass gives the chosen vertices exactly as
the full model would, at a fraction of the cost (fitting needs only landmark vertices).
"""

from __future__ import annotations

import numpy as np

from .model import N_JOINTS, FlameModel


def vertex_subset(model: FlameModel, vertex_ids) -> FlameModel:
    """The model's vertices `vertex_ids` (in that order), then the 5 joint carriers."""
    ids = np.asarray(vertex_ids, np.int64)
    n = len(ids)
    j_template = model.j_regressor @ model.v_template  # (5,3)
    j_dirs = np.einsum("jv,vck->jck", model.j_regressor, model.shapedirs)
    picker = np.zeros((N_JOINTS, n + N_JOINTS))
    picker[:, n:] = np.eye(N_JOINTS)
    weights = np.concatenate([model.weights[ids], np.eye(N_JOINTS)])
    return FlameModel(
        v_template=np.concatenate([model.v_template[ids], j_template]),
        faces=np.zeros((0, 3), np.int64),
        shapedirs=np.concatenate([model.shapedirs[ids], j_dirs]),
        n_shape=model.n_shape,
        posedirs=np.concatenate(
            [model.posedirs[ids], np.zeros((N_JOINTS, *model.posedirs.shape[1:]))]
        ),
        j_regressor=picker,
        weights=weights,
        parents=model.parents,
        model_id=f"{model.model_id}[{n} vertices]",
        source=model.source,
    )
