"""FLAME as a Blender-style rig, computed without Blender.

An armature reproduces FLAME's skinning exactly when every bone's rest frame is axis-aligned
in FLAME space (bone along +y, roll 0) at the rest joint J0 of the identity-shaped template.
Two FLAME effects need care:
- expressions move the joints (J = J_regressor (T + B_S + B_E)); a pose-bone location of
  (I - R_i) dJ_i (plus the translation on the root) makes the bone act as if its joint were
  at J0_i + dJ_i (derivation in docs/rig.md);
- pose correctives are shape keys whose values are the 36 entries of (R_i - I), written as
  quadratic expressions of each bone's quaternion so simple-expression drivers evaluate them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .flame.model import JOINT_NAMES, FlameModel
from .rotations import axis_angle_to_matrix, axis_angle_to_quaternion

# (R - I)[r, c] for a unit quaternion (w, x, y, z), row-major like FLAME's pose feature
POSE_FEATURE_EXPRESSIONS = (
    "-2*(y*y+z*z)",
    "2*(x*y-w*z)",
    "2*(x*z+w*y)",
    "2*(x*y+w*z)",
    "-2*(x*x+z*z)",
    "2*(y*z-w*x)",
    "2*(x*z-w*y)",
    "2*(y*z+w*x)",
    "-2*(x*x+y*y)",
)


def pose_corrective_names() -> list[tuple[str, str, int]]:
    """(shape key name, bone name, feature entry 0..8) for the 36 correctives, FLAME order."""
    return [
        (f"pose_{bone}_{r}{c}", bone, 3 * r + c)
        for bone in JOINT_NAMES[1:]
        for r in range(3)
        for c in range(3)
    ]


@dataclass
class RigAnimation:
    rest_vertices: np.ndarray  # (V,3) template + identity shape (+ static offset)
    rest_joints: np.ndarray  # (5,3)
    expr_deltas: np.ndarray  # (E,V,3) shape-key offsets of the kept expressions
    pose_deltas: np.ndarray  # (36,V,3) shape-key offsets of the pose correctives
    expr: np.ndarray  # (T,E) shape-key values
    bone_quats: np.ndarray  # (T,5,4) w,x,y,z, sign-continuous over time
    bone_locs: np.ndarray  # (T,5,3) pose-bone locations
    pose_feature: np.ndarray  # (T,36) the pose correctives' values, vec(R_i - I), FLAME order
    identity_shape: np.ndarray  # (S,)
    identity_offset: np.ndarray | None  # (V,3) the sequence's static offset, if it has one
    # The expression components (columns of expr) the sequence moves: the only ones given a
    # shape key; the others stay zero on every frame, so their keys would only cost memory.
    used_expr: np.ndarray  # (U,) int


def rig_animation(model: FlameModel, seq, n_expr: int | None = None) -> RigAnimation:
    """The rig's rest state and per-frame channels for a sequence fitted to the model."""
    n_expr = model.n_expr if n_expr is None else min(n_expr, model.n_expr)
    used = np.flatnonzero(np.any(np.asarray(seq.expr)[:, :n_expr] != 0, axis=0))
    n_expr = int(used[-1]) + 1 if len(used) else 0  # trailing unused components: not even kept
    shape = np.asarray(seq.shape, dtype=np.float64)
    identity = shape[0] if shape.ndim == 2 else shape
    n_s = identity.shape[0]
    rest = model.v_template + model.shapedirs[:, :, :n_s] @ identity
    offset = getattr(seq, "static_offset", None)
    if offset is not None:
        offset = np.asarray(offset, dtype=np.float64).reshape(-1, 3)[: model.n_verts]
        rest = rest + offset
    rest_joints = model.j_regressor @ rest
    e0 = model.n_shape
    expr_dirs = np.moveaxis(model.shapedirs[:, :, e0 : e0 + n_expr], 2, 0)  # (E,V,3)
    expr = np.asarray(seq.expr, dtype=np.float64)[:, :n_expr]
    # joint displacement per expression unit: (E,5,3)
    joint_dirs = np.einsum("jv,evc->ejc", model.j_regressor, expr_dirs)
    d_joints = np.einsum("te,ejc->tjc", expr, joint_dirs)
    pose = np.stack([seq.rotation, seq.neck, seq.jaw, seq.eyes[:, :3], seq.eyes[:, 3:]], 1)
    rot = axis_angle_to_matrix(pose)  # (T,5,3,3)
    locs = d_joints - np.einsum("tjrc,tjc->tjr", rot, d_joints)
    locs[:, 0] += np.asarray(seq.translation, dtype=np.float64)
    return RigAnimation(
        rest_vertices=rest,
        rest_joints=rest_joints,
        expr_deltas=expr_dirs,
        pose_deltas=np.moveaxis(model.posedirs, 2, 0),
        expr=expr,
        bone_quats=continuous_quaternions(axis_angle_to_quaternion(pose)),
        bone_locs=locs,
        pose_feature=(rot[:, 1:] - np.eye(3)).reshape(len(rot), -1),
        identity_shape=identity,
        identity_offset=offset,
        used_expr=used,
    )


def continuous_quaternions(q: np.ndarray) -> np.ndarray:
    """Flip signs over time (axis 0) so consecutive keys interpolate the short way."""
    q = q.copy()
    for t in range(1, len(q)):
        flip = np.sum(q[t] * q[t - 1], axis=-1) < 0
        q[t][flip] *= -1
    return q
