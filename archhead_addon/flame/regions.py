"""The head of a FLAME-format model without its neck, for masks and region metrics.

FLAME's mesh carries a neck down to the collar, but the comparable methods score the head
and its neck only where the person's own neck shows, and an artist's avatar is judged on the
face. The cut needs no labels, so it holds for the built-in head and any user's FLAME file:
behind the neck joint it is the horizontal plane through the joint (the base of the skull);
in front it slopes down to the lowest point of the jaw, so the chin and the jaw's underside
stay in the head and the throat falls to the neck. Positions are the template's (y up, z
forward), which is where the joints are defined.
"""

from __future__ import annotations

import numpy as np

from .model import FlameModel

NECK_JOINT, JAW_JOINT = 1, 2
JAW_WEIGHT = 0.5  # a vertex belongs to the jaw where the jaw joint moves it at least this much


def head_vertices(model: FlameModel) -> np.ndarray:
    """(V,) bool: the vertices above the neck cut (module docstring)."""
    v = model.v_template
    joints = model.j_regressor @ v
    y0, z0 = joints[NECK_JOINT, 1], joints[NECK_JOINT, 2]
    jaw = (model.weights[:, JAW_JOINT] > JAW_WEIGHT) & (v[:, 2] > z0)
    if not jaw.any():  # no jaw in front of the neck joint: the horizontal plane alone
        return v[:, 1] > y0
    lowest = np.flatnonzero(jaw)[np.argmin(v[jaw, 1])]
    slope = (v[lowest, 1] - y0) / max(v[lowest, 2] - z0, 1e-6)
    return v[:, 1] > y0 + slope * np.maximum(v[:, 2] - z0, 0.0)


def head_faces(model: FlameModel) -> np.ndarray:
    """(F,) bool: faces whose three vertices are all in the head."""
    return head_vertices(model)[model.faces].all(axis=1)
