"""The head of a FLAME-format model without its neck, for masks and region metrics.

FLAME's mesh carries a neck down to the collar, but the comparable methods score the head
and its neck only where the person's own neck shows, and an artist's avatar is judged on the
face. The cut needs no labels, so it holds for the built-in head and any user's FLAME file:
behind the neck joint it is the horizontal plane through the joint (the base of the skull);
in front it slopes down to the lowest point of the jaw, so the chin and the jaw's underside
stay in the head and the throat falls to the neck. Positions are the template's (y up, z
forward), which is where the joints are defined.

The face, for scores that no hair reaches unless it falls over it: the head's vertices in
front of the ears (60 % of the way from the neck joint to the eyes) and below the upper
forehead (40 % of the eyes-to-chin height above the eyes): eyes, nose, mouth, cheeks, chin
and the forehead's lower part, again from the joints alone.
"""

from __future__ import annotations

import numpy as np

from .model import FlameModel

NECK_JOINT, JAW_JOINT, EYE_JOINTS = 1, 2, (3, 4)
JAW_WEIGHT = 0.5  # a vertex belongs to the jaw where the jaw joint moves it at least this much
# The face's edges, from the joints (module docstring): in front of the point 60 % of the way
# from the neck joint to the eyes (the ears and the temples' sides behind it), below 40 % of
# the eyes-to-chin height above the eyes (the upper forehead, under a hairline).
FACE_FRONT, FACE_TOP = 0.6, 0.4


def _chin(model: FlameModel) -> np.ndarray | None:
    """The template position of the jaw's lowest vertex in front of the neck joint."""
    v = model.v_template
    z0 = (model.j_regressor @ v)[NECK_JOINT, 2]
    jaw = (model.weights[:, JAW_JOINT] > JAW_WEIGHT) & (v[:, 2] > z0)
    return v[np.flatnonzero(jaw)[np.argmin(v[jaw, 1])]] if jaw.any() else None


def head_vertices(model: FlameModel) -> np.ndarray:
    """(V,) bool: the vertices above the neck cut (module docstring)."""
    v = model.v_template
    joints = model.j_regressor @ v
    y0, z0 = joints[NECK_JOINT, 1], joints[NECK_JOINT, 2]
    chin = _chin(model)
    if chin is None:  # no jaw in front of the neck joint: the horizontal plane alone
        return v[:, 1] > y0
    slope = (chin[1] - y0) / max(chin[2] - z0, 1e-6)
    return v[:, 1] > y0 + slope * np.maximum(v[:, 2] - z0, 0.0)


def face_vertices(model: FlameModel) -> np.ndarray:
    """(V,) bool: the face, the head's front below its forehead (module docstring); where
    hair cannot fall unless it falls over the face."""
    v = model.v_template
    joints = model.j_regressor @ v
    eyes, neck, chin = joints[list(EYE_JOINTS)].mean(axis=0), joints[NECK_JOINT], _chin(model)
    front = neck[2] + FACE_FRONT * (eyes[2] - neck[2])
    top = eyes[1] + FACE_TOP * (eyes[1] - (neck[1] if chin is None else chin[1]))
    return head_vertices(model) & (v[:, 2] > front) & (v[:, 1] < top)


def head_faces(model: FlameModel) -> np.ndarray:
    """(F,) bool: faces whose three vertices are all in the head."""
    return head_vertices(model)[model.faces].all(axis=1)


def face_faces(model: FlameModel) -> np.ndarray:
    """(F,) bool: faces whose three vertices are all in the face."""
    return face_vertices(model)[model.faces].all(axis=1)
