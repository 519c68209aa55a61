"""FLAME forward pass in numpy: blendshapes, pose correctives, linear blend skinning.

v = LBS(T + B_S(shape) + B_E(expr) + B_P(pose), J(T + B_S + B_E), pose) + translation,
with the global rotation about joint 0 (FLAME's convention) and the translation added last.
The torch twin (`lbs_torch.py`) computes the same thing; tests hold them together.
"""

from __future__ import annotations

import weakref
from typing import NamedTuple

import numpy as np

from ..rotations import axis_angle_to_matrix
from .model import N_JOINTS, FlameModel

CODE_DIMS = {"rotation": 3, "neck": 3, "jaw": 3, "eyes": 6, "translation": 3}


class FlameOutput(NamedTuple):
    vertices: np.ndarray  # (B,V,3)
    joints: np.ndarray  # (B,5,3) posed joint positions, translation included
    transforms: np.ndarray  # (B,5,4,4) skinning transforms (rest space -> posed, no translation)


_cast_cache: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def model_arrays(model: FlameModel, dtype) -> dict[str, np.ndarray]:
    """The model's arrays in `dtype`, laid out for matrix products; cached per model."""
    per_model = _cast_cache.setdefault(model, {})
    key = np.dtype(dtype).str
    if key not in per_model:
        v = model.n_verts
        per_model[key] = {
            "v_template": model.v_template.astype(dtype),
            # (S+E, 3V): a code's block is whole rows, read in order (a column slice of
            # (3V, S+E) took 2-3x as long for one frame's expression: flame_forward.py)
            "shapedirs": np.ascontiguousarray(model.shapedirs.reshape(v * 3, -1).T, dtype),
            "posedirs": model.posedirs.reshape(v * 3, -1).astype(dtype),  # (3V, 36)
            "j_regressor": model.j_regressor.astype(dtype),
            "weights": model.weights.astype(dtype),
        }
    return per_model[key]


def batch_codes(model: FlameModel, codes: dict, xp=np):
    """Give every code a batch dimension, fill absent ones with zeros, check the widths.

    Fewer shape/expression components than the model has use the leading ones; more are an
    error (a sequence is fitted to the model, with a warning, before it gets here).
    """
    given = {k: v for k, v in codes.items() if v is not None}
    # static_offset (V,3) is per vertex, not per frame: it never sets the batch
    batch = max(
        (v.shape[0] for k, v in given.items() if v.ndim == 2 and k != "static_offset"), default=1
    )
    limits = {"shape": model.n_shape, "expr": model.n_expr, **CODE_DIMS}
    out = {}
    for key, width in limits.items():
        value = given.get(key)
        if value is None:
            out[key] = None if key in ("shape", "expr") else width
            continue
        if value.ndim == 1:
            value = value[None]
        if value.ndim != 2 or value.shape[0] not in (1, batch):
            raise ValueError(
                f"FLAME code '{key}': expected ({batch}, n), found {tuple(value.shape)}"
            )
        exact = key not in ("shape", "expr")
        if (exact and value.shape[1] != width) or value.shape[1] > width:
            raise ValueError(
                f"FLAME code '{key}': width {value.shape[1]}, the model takes "
                f"{'exactly' if exact else 'at most'} {width}"
            )
        out[key] = value
    unknown = set(codes) - set(limits) - {"static_offset"}
    if unknown:
        raise ValueError(f"unknown FLAME codes: {sorted(unknown)}")
    return batch, out


def forward(model: FlameModel, **codes) -> np.ndarray:
    """Posed vertices (B,V,3). Codes: shape, expr, rotation, neck, jaw, eyes, translation,
    static_offset (V,3); each (B,n) or (n,); absent codes are zero."""
    return forward_full(model, **codes).vertices


def forward_full(model: FlameModel, dtype=np.float64, **codes) -> FlameOutput:
    arrays = model_arrays(model, dtype)
    codes = {k: None if v is None else np.asarray(v, dtype=dtype) for k, v in codes.items()}
    batch, c = batch_codes(model, codes)

    def code(key):
        v = c[key]
        return (
            np.zeros((batch, v), dtype)
            if isinstance(v, int)
            else np.broadcast_to(v, (batch, v.shape[1]))
        )

    n_v = model.n_verts
    v_shaped = np.broadcast_to(arrays["v_template"], (batch, n_v, 3)).copy()
    if codes.get("static_offset") is not None:
        v_shaped += codes["static_offset"].reshape(n_v, 3)
    for key, start in (("shape", 0), ("expr", model.n_shape)):
        if c[key] is not None:
            k = c[key].shape[1]
            coeffs = np.broadcast_to(c[key], (batch, k))
            v_shaped += (coeffs @ arrays["shapedirs"][start : start + k]).reshape(batch, n_v, 3)

    # matrix products rather than einsum: 3-6x faster (benchmarks/flame_forward.py; a crowd's far
    # heads decode one frame each)
    joints_rest = arrays["j_regressor"] @ v_shaped  # (B,5,3)
    pose = np.stack(
        [code("rotation"), code("neck"), code("jaw"), code("eyes")[:, :3], code("eyes")[:, 3:]],
        axis=1,
    )  # (B,5,3)
    rot = axis_angle_to_matrix(pose)  # (B,5,3,3)
    feature = (rot[:, 1:] - np.eye(3, dtype=dtype)).reshape(batch, -1)  # (B,36)
    v_posed = v_shaped + (feature @ arrays["posedirs"].T).reshape(batch, n_v, 3)

    transforms = _chain(rot, joints_rest, model.parents)
    blend = (arrays["weights"] @ transforms[:, :, :3, :].reshape(batch, N_JOINTS, 12)).reshape(
        batch, n_v, 3, 4
    )
    verts = np.einsum("bvrc,bvc->bvr", blend[..., :3], v_posed) + blend[..., 3]
    trans = code("translation")[:, None, :]
    joints = np.einsum("bjrc,bjc->bjr", transforms[:, :, :3, :3], joints_rest)
    joints += transforms[:, :, :3, 3] + trans
    return FlameOutput(verts + trans, joints, transforms)


def _chain(rot: np.ndarray, joints: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """World transforms of the kinematic chain, re-based so they act on rest-pose points."""
    batch = rot.shape[0]
    local = np.zeros((batch, N_JOINTS, 4, 4), rot.dtype)
    local[:, :, :3, :3] = rot
    local[:, :, 3, 3] = 1
    rel = joints.copy()
    rel[:, 1:] -= joints[:, parents[1:]]
    local[:, :, :3, 3] = rel
    world = [local[:, 0]]
    for j in range(1, N_JOINTS):
        world.append(world[parents[j]] @ local[:, j])
    world = np.stack(world, axis=1)
    world[:, :, :3, 3] -= np.einsum("bjrc,bjc->bjr", world[:, :, :3, :3], joints)
    return world
