"""FLAME codes from the imported rig's channels: the inverse of `rig.rig_animation`.

The rig keys, per bone i, the local rotation R_i and a location t_i that stands in for the
expression's joint displacement dJ_i (docs/rig.md): t_i = (I - R_i) dJ_i, and on the root
t_0 = translation + (I - R_0) dJ_0. So the translation is t_0 - (I - R_0) dJ_0, with dJ_0
regressed from the expression values the head carries; non-root bone locations carry no code
of their own (an artist's move of them has no FLAME meaning and is ignored).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, fields

import numpy as np

from ..flame.model import FlameModel
from ..rotations import matrix_to_axis_angle

N_JOINTS = 5  # global, neck, jaw, eye_left, eye_right (flame.model.JOINT_NAMES)


@dataclass(frozen=True)
class FrameCodes:
    """One frame's FLAME codes in the keyword names of `AvatarRuntime.decode`."""

    expr: np.ndarray  # (E,)
    rotation: np.ndarray  # (3,) axis-angle of the global joint
    neck: np.ndarray  # (3,)
    jaw: np.ndarray  # (3,)
    eyes: np.ndarray  # (6,) left then right eye
    translation: np.ndarray  # (3,)

    def as_kwargs(self) -> dict[str, np.ndarray]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def digest(self) -> str:
        """Names the codes in cache keys: a hash of their float32 values (what Blender holds).
        Kept with the codes (their arrays are not changed once made), as every refresh of a
        head that did not move asks again."""
        known = self.__dict__.get("_digest")
        if known is None:
            h = hashlib.sha1()
            for f in fields(self):
                h.update(np.ascontiguousarray(getattr(self, f.name), np.float32).tobytes())
            known = h.hexdigest()
            object.__setattr__(self, "_digest", known)
        return known


def expression_joint_dirs(model: FlameModel, n_expr: int) -> np.ndarray:
    """(E,5,3): the joints' displacement per unit of each of the first n_expr expressions."""
    e0 = model.n_shape
    dirs = model.shapedirs[:, :, e0 : e0 + n_expr]  # (V,3,E)
    return np.einsum("jv,vce->ejc", model.j_regressor, dirs)


def codes_from_rig(
    rotations: np.ndarray, root_location: np.ndarray, expr: np.ndarray, joint_dirs: np.ndarray
) -> FrameCodes:
    """Codes from the bones' local rotation matrices (5,3,3), the root bone's location (3,),
    the expression shape-key values (E,) and `expression_joint_dirs` (>= E rows)."""
    rotations = np.asarray(rotations, np.float64)
    expr = np.asarray(expr, np.float64).reshape(-1)
    if rotations.shape != (N_JOINTS, 3, 3):
        raise ValueError(f"expected (5,3,3) bone rotations, got {rotations.shape}")
    if len(expr) > len(joint_dirs):
        raise ValueError(f"{len(expr)} expression values, the model has {len(joint_dirs)}")
    aa = matrix_to_axis_angle(rotations)  # (5,3)
    d_root = expr @ joint_dirs[: len(expr), 0]  # the root joint's expression displacement
    r0 = rotations[0]
    translation = np.asarray(root_location, np.float64) - (d_root - r0 @ d_root)
    return FrameCodes(
        expr=expr,
        rotation=aa[0],
        neck=aa[1],
        jaw=aa[2],
        eyes=np.concatenate([aa[3], aa[4]]),
        translation=translation,
    )
