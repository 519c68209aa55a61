"""The built-in head model: a generated FLAME-format head, the default when no FLAME file
is given (the demo and the tests use it).

`builtin_model()` returns it, generated in a few seconds on first use and then read from a
cache file (`$ARCHHEAD_CACHE`, else `~/.cache/archhead`) named by GENERATOR_VERSION; bump
the version whenever the generator's output changes. Generation is deterministic: the same
arrays, bit for bit, on every run (seeded randomness; sums in numpy's own loops, not in
multi-threaded BLAS).

What it contains (see the modules): `sculpt` (the shape), `mesh` (topology, UVs), `rig`
(joints, skinning, pose correctives), `blendshapes` (300 identity and 100 expression
components; IDENTITY_NAMES and EXPRESSION_NAMES give the leading ones in order),
`texture` (the albedo).
"""

from __future__ import annotations

import os
import warnings
import zipfile
from pathlib import Path

import numpy as np

from ...io.atomic import save_npz_atomic
from ..model import PART_EYE, PART_MOUTH, FlameModel, model_from_arrays
from .blendshapes import (
    EXPRESSION_NAMES,
    IDENTITY_NAMES,
    N_IDENTITY,
    expression_basis,
    identity_basis,
)
from .fields import bump
from .mesh import HeadMesh, build_head, closed_lids, eye_centres
from .rig import joint_regressor, pose_correctives, skinning_weights
from .sculpt import vermilion
from .texture import paint_albedo

GENERATOR_VERSION = 1
MODEL_ID = "archhead-builtin-v1"
KINTREE = np.array([[4294967295, 0, 1, 1, 1], [0, 1, 2, 3, 4]], dtype=np.int64)

__all__ = [
    "EXPRESSION_NAMES",
    "GENERATOR_VERSION",
    "IDENTITY_NAMES",
    "MODEL_ID",
    "builtin_model",
    "cache_path",
    "generate_arrays",
]


def _vertex_parts(head: HeadMesh) -> np.ndarray:
    v = head.verts
    parts = np.zeros(len(v), np.uint8)
    near_eyes = sum(bump(v, c + [0, 0.002, 0.010], [0.022, 0.017, 0.016]) for c in eye_centres())
    parts[near_eyes > 0.05] = PART_EYE
    for name in ("eyeball_left", "eyeball_right", "lid_margin_left", "lid_margin_right"):
        parts[head.groups[name]] = PART_EYE
    parts[vermilion(v) > 0.2] = PART_MOUTH
    for name in ("lip_ring_upper", "lip_ring_lower", "mouth_cavity_rings", "mouth_cavity_centre"):
        parts[head.groups[name].ravel()] = PART_MOUTH
    return parts


def generate_arrays() -> dict[str, np.ndarray]:
    """The model in file form (the keys of `flame.model`), generated from scratch."""
    head = build_head()
    blinks = [closed_lids(head, b) - head.verts for b in ((1.0, 0.0), (0.0, 1.0))]
    regressor = joint_regressor(head)
    joints = (regressor[:, :, None] * head.verts[None]).sum(1)
    weights = skinning_weights(head, joints)
    shapedirs = np.concatenate(
        [identity_basis(head), expression_basis(head, weights[:, 2], joints[2], blinks)], axis=2
    )
    f32 = np.float32
    return {
        "v_template": head.verts.astype(f32),
        "f": head.faces.astype(np.int32),
        "shapedirs": shapedirs.astype(f32),
        "posedirs": pose_correctives(head, joints, weights).astype(f32),
        "J_regressor": regressor.astype(f32),
        "weights": weights.astype(f32),
        "kintree_table": KINTREE,
        "n_shape": np.int64(N_IDENTITY),
        "model_id": np.str_(MODEL_ID),
        "vt": head.uv.astype(f32),
        "ft": head.uv_faces.astype(np.int32),
        "lip_ring_upper": head.groups["lip_ring_upper"].astype(np.int32),
        "lip_ring_lower": head.groups["lip_ring_lower"].astype(np.int32),
        "vertex_parts": _vertex_parts(head),
        "albedo": paint_albedo(head),
        "generator_version": np.int64(GENERATOR_VERSION),
    }


def cache_path(cache_dir=None) -> Path:
    folder = Path(cache_dir or os.environ.get("ARCHHEAD_CACHE") or Path.home() / ".cache/archhead")
    return folder / f"builtin_head_v{GENERATOR_VERSION}.npz"


_MEMORY: dict[Path, FlameModel] = {}


def builtin_model(cache_dir=None) -> FlameModel:
    """The built-in head (shared instance: do not modify its arrays in place)."""
    path = cache_path(cache_dir)
    if path not in _MEMORY:
        _MEMORY[path] = model_from_arrays(_load_or_generate(path), source="builtin")
    return _MEMORY[path]


def _load_or_generate(path: Path) -> dict:
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        if int(arrays.get("generator_version", -1)) == GENERATOR_VERSION:
            return arrays
    except FileNotFoundError:
        pass
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        warnings.warn(
            f"{path}: unreadable built-in model cache ({exc}); regenerating", stacklevel=3
        )
    arrays = generate_arrays()
    try:
        save_npz_atomic(path, **arrays)
    except OSError as exc:
        warnings.warn(f"{path}: cannot cache the built-in model ({exc})", stacklevel=3)
    return arrays
