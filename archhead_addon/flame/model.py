"""The FLAME-format model in memory and its readers (official pickles and npz).

Keys (as in the official files): `v_template` (V,3), `f` (F,3), `shapedirs` (V,3,S+E:
identity then expression), `posedirs` (V,3,36), `J_regressor` (5,V), `weights` (V,5),
`kintree_table` (2,5). Optional keys that ArchHead models add (the built-in one has all):
`n_shape` (how many of the shapedirs are identity; default min(300, S+E)), `vt` (Vt,2) and
`ft` (F,3) UVs, `lip_ring_upper` / `lip_ring_lower` (vertex index loops for teeth),
`vertex_parts` (V,) uint8 (0 other, 1 eye region, 2 mouth region), `albedo` (H,W,3) uint8,
`model_id` (a string naming the topology, used to match avatars with heads).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..io.errors import InputError, warn_input
from ..io.npz import read_npz
from ..io.safe_pickle import safe_load
from ..io.schema import check_range, integers, numeric

JOINT_NAMES = ("global", "neck", "jaw", "eye_left", "eye_right")
N_JOINTS = len(JOINT_NAMES)
N_POSE_CORRECTIVES = 9 * (N_JOINTS - 1)  # (R - I) of every joint but the root
PART_OTHER, PART_EYE, PART_MOUTH = 0, 1, 2


@dataclass(frozen=True, eq=False)
class FlameModel:
    v_template: np.ndarray  # (V,3) float64, metres, y up
    faces: np.ndarray  # (F,3) int64
    shapedirs: np.ndarray  # (V,3,n_shape+n_expr)
    n_shape: int
    posedirs: np.ndarray  # (V,3,36)
    j_regressor: np.ndarray  # (5,V) dense
    weights: np.ndarray  # (V,5)
    parents: np.ndarray  # (5,) int64, -1 for the root
    model_id: str
    source: str = "<memory>"
    uv: np.ndarray | None = None  # (Vt,2) in [0,1]
    uv_faces: np.ndarray | None = None  # (F,3) into uv
    lip_ring_upper: np.ndarray | None = None
    lip_ring_lower: np.ndarray | None = None
    vertex_parts: np.ndarray | None = None  # (V,) uint8
    albedo: np.ndarray | None = None  # (H,W,3) uint8
    extras: dict = field(default_factory=dict)  # e.g. teeth bookkeeping

    @property
    def n_verts(self) -> int:
        return self.v_template.shape[0]

    @property
    def n_expr(self) -> int:
        return self.shapedirs.shape[2] - self.n_shape

    def replace(self, **changes) -> FlameModel:
        return replace(self, **changes)

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The model in file form (the keys of the module docstring)."""
        kintree = np.stack([self.parents, np.arange(N_JOINTS)]).astype(np.int64)
        kintree[0, self.parents < 0] = 4294967295  # the official files' root marker
        out = {
            "v_template": self.v_template,
            "f": self.faces,
            "shapedirs": self.shapedirs,
            "posedirs": self.posedirs,
            "J_regressor": self.j_regressor,
            "weights": self.weights,
            "kintree_table": kintree,
            "n_shape": np.int64(self.n_shape),
            "model_id": np.str_(self.model_id),
        }
        optional = {
            "vt": self.uv,
            "ft": self.uv_faces,
            "lip_ring_upper": self.lip_ring_upper,
            "lip_ring_lower": self.lip_ring_lower,
            "vertex_parts": self.vertex_parts,
            "albedo": self.albedo,
        }
        out.update({k: v for k, v in optional.items() if v is not None})
        return out


def load_model(path=None) -> FlameModel:
    """Read a FLAME model: None = the built-in model; .pkl (2020 / 2023); .npz."""
    if path is None or str(path) == "":
        from .builtin import builtin_model

        return builtin_model()
    path = Path(path)
    if not path.is_file():
        raise InputError(path, None, "FLAME model file not found")
    if path.suffix.lower() == ".npz":
        arrays = read_npz(path, what="npz file")
    else:
        arrays = safe_load(path)
        if not isinstance(arrays, dict):
            raise InputError(
                path, None, f"expected a dict of arrays, found {type(arrays).__name__}"
            )
    return model_from_arrays(arrays, source=str(path))


def _get(arrays, key, source, ndim, dtype=np.float64):
    """A key as `dtype` with `ndim` dimensions: integer keys must hold whole numbers, float
    ones finite values within float32's range (the runtime's)."""
    if key not in arrays:
        raise InputError(source, key, "missing")
    if dtype == np.float64:
        a = numeric(arrays[key], source, key)
    else:
        a = integers(arrays[key], source, key)
    if a.ndim != ndim:
        raise InputError(source, key, f"expected {ndim} dimensions, found shape {a.shape}")
    if dtype == np.float64:
        check_range(a, source, key)
    elif dtype == np.uint8 and a.size and (a.min() < 0 or a.max() > 255):
        raise InputError(source, key, "values outside 0..255")
    return a.astype(dtype)


def model_from_arrays(arrays: dict, source: str = "<memory>") -> FlameModel:
    """Validate the file keys and build a FlameModel; every error names the key."""
    v = _get(arrays, "v_template", source, 2)
    n_v = v.shape[0]
    if v.shape[1] != 3 or n_v == 0:
        raise InputError(source, "v_template", f"expected (V,3), found {v.shape}")
    check_range(v, source, "v_template", plausible=10.0, reason="metres; a head is 0.3 m")
    faces = _get(arrays, "f", source, 2, np.int64)
    if faces.shape[1:] != (3,) or len(faces) == 0 or faces.min() < 0 or faces.max() >= n_v:
        raise InputError(source, "f", f"expected (F,3) indices below {n_v}, F > 0")
    shapedirs = _get(arrays, "shapedirs", source, 3)
    posedirs = _get(arrays, "posedirs", source, 3)
    jreg = _get(arrays, "J_regressor", source, 2)
    weights = _get(arrays, "weights", source, 2)
    kintree = _get(arrays, "kintree_table", source, 2, np.int64)
    for key, a, want in (("shapedirs", shapedirs, (n_v, 3)), ("posedirs", posedirs, (n_v, 3))):
        if a.shape[:2] != want:
            raise InputError(source, key, f"expected ({n_v}, 3, K), found {a.shape}")
    if posedirs.shape[2] != N_POSE_CORRECTIVES:
        raise InputError(
            source,
            "posedirs",
            f"expected {N_POSE_CORRECTIVES} pose correctives "
            f"(4 joints x 9), found {posedirs.shape[2]}",
        )
    if jreg.shape != (N_JOINTS, n_v):
        raise InputError(source, "J_regressor", f"expected ({N_JOINTS}, {n_v}), found {jreg.shape}")
    if weights.shape != (n_v, N_JOINTS):
        raise InputError(source, "weights", f"expected ({n_v}, {N_JOINTS}), found {weights.shape}")
    if kintree.shape != (2, N_JOINTS):
        raise InputError(
            source, "kintree_table", f"expected (2, {N_JOINTS}), found {kintree.shape}"
        )
    _check_rig(v, shapedirs, posedirs, jreg, weights, source)
    parents = _parents(kintree, source)
    n_total = shapedirs.shape[2]
    n_shape = min(300, n_total)
    if "n_shape" in arrays:
        n_shape = integers(arrays["n_shape"], source, "n_shape")
        if n_shape.shape not in ((), (1,)):
            raise InputError(source, "n_shape", f"expected one integer, found {n_shape.shape}")
        n_shape = int(n_shape.reshape(()))
    if not 0 <= n_shape <= n_total:
        raise InputError(source, "n_shape", f"{n_shape} outside 0..{n_total}")
    if n_total - n_shape == 0:
        warn_input(source, "shapedirs", "no expression components; expressions will be ignored")
    model_id = _model_id(arrays, source) if "model_id" in arrays else _topology_id(v, faces)
    opt = {}
    for key, name, dtype, ndim in (
        ("vt", "uv", np.float64, 2),
        ("ft", "uv_faces", np.int64, 2),
        ("lip_ring_upper", "lip_ring_upper", np.int64, 1),
        ("lip_ring_lower", "lip_ring_lower", np.int64, 1),
        ("vertex_parts", "vertex_parts", np.uint8, 1),
        ("albedo", "albedo", np.uint8, 3),
    ):
        if key in arrays:
            opt[name] = _get(arrays, key, source, ndim, dtype)
    _check_optional(opt, n_v, faces.shape[0], source)
    return FlameModel(
        v_template=v,
        faces=faces,
        shapedirs=shapedirs,
        n_shape=n_shape,
        posedirs=posedirs,
        j_regressor=jreg,
        weights=weights,
        parents=parents,
        model_id=model_id,
        source=source,
        **opt,
    )


SUM_TOLERANCE = 1e-3  # FLAME's rows sum to 1 within 1e-7 (float32)


def _check_rig(v, shapedirs, posedirs, jreg, weights, source) -> None:
    """What every FLAME-layout model is: a template of some size; blendshapes that move a
    vertex by less than the head's size per unit coefficient (FLAME's: 1/40 of it); skinning
    weights in 0..1 summing to 1 per vertex, joint regressor rows summing to 1 (a joint is
    an average of vertices: anything else moves the joints when the head merely moves)."""
    extent = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    if not extent > 1e-6:
        raise InputError(source, "v_template", "every vertex at one point (a head has a size)")
    for key, dirs in (("shapedirs", shapedirs), ("posedirs", posedirs)):
        largest = float(np.abs(dirs).max(initial=0))
        if largest > extent:
            raise InputError(
                source,
                key,
                f"displacement {largest:.3g} per unit coefficient is more than the template's "
                f"whole size {extent:.3g} (FLAME's are 1/40 of it)",
            )
    tol = SUM_TOLERANCE
    bad = (weights < -tol).any(axis=1) | (weights > 1 + tol).any(axis=1)
    bad |= np.abs(weights.sum(axis=1) - 1) > tol
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError(
            source,
            "weights",
            f"vertex {i}'s skinning weights {np.round(weights[i], 4).tolist()} are not in 0..1 "
            "summing to 1",
        )
    sums = jreg.sum(axis=1)
    bad = np.abs(sums - 1) > tol
    if bad.any():
        j = int(np.argmax(bad))
        raise InputError(
            source,
            "J_regressor",
            f"joint {j}'s row sums to {sums[j]:.4g}, not 1 (a joint is an average of vertices)",
        )


def _parents(kintree: np.ndarray, source) -> np.ndarray:
    order = kintree[1]
    if sorted(order.tolist()) != list(range(N_JOINTS)):
        raise InputError(source, "kintree_table", f"row 1 must list joints 0..4, found {order}")
    parents = np.full(N_JOINTS, -1, dtype=np.int64)
    for p, j in zip(kintree[0], order, strict=True):
        parents[j] = p if 0 <= p < N_JOINTS else -1
    roots = np.flatnonzero(parents < 0)
    if roots.tolist() != [0] or any(parents[j] >= j for j in range(1, N_JOINTS)):
        raise InputError(
            source,
            "kintree_table",
            "joint 0 must be the only root and parents "
            f"must come before children; parents are {parents.tolist()}",
        )
    return parents


def _check_optional(opt: dict, n_v: int, n_f: int, source) -> None:
    if ("uv" in opt) != ("uv_faces" in opt):
        raise InputError(source, "vt" if "uv" not in opt else "ft", "vt and ft come together")
    if "uv_faces" in opt:
        ft, n_vt = opt["uv_faces"], opt["uv"].shape[0]
        if opt["uv"].shape[1:] != (2,):
            raise InputError(source, "vt", f"expected (Vt, 2), found {opt['uv'].shape}")
        if ft.shape != (n_f, 3) or ft.min(initial=0) < 0 or ft.max(initial=0) >= n_vt:
            raise InputError(source, "ft", f"expected ({n_f}, 3) indices below {n_vt}")
    for key in ("lip_ring_upper", "lip_ring_lower"):
        if key in opt and (opt[key].min(initial=0) < 0 or opt[key].max(initial=0) >= n_v):
            raise InputError(source, key, f"vertex indices outside 0..{n_v - 1}")
    if "vertex_parts" in opt and opt["vertex_parts"].shape != (n_v,):
        raise InputError(source, "vertex_parts", f"expected ({n_v},)")
    if "albedo" in opt and (opt["albedo"].shape[2] != 3 or 0 in opt["albedo"].shape):
        raise InputError(source, "albedo", f"expected (H, W, 3), found {opt['albedo'].shape}")


def _model_id(arrays, source) -> str:
    value = arrays["model_id"]
    if not isinstance(value, str | np.ndarray) or np.ndim(value) != 0 or len(str(value)) > 200:
        raise InputError(source, "model_id", "expected a short string")
    return str(value)


def _topology_id(v: np.ndarray, faces: np.ndarray) -> str:
    """Names the topology (vertex count + face hash) so avatars can be matched to heads."""
    digest = hashlib.sha1(np.ascontiguousarray(faces, dtype=np.int64).tobytes()).hexdigest()[:12]
    return f"flame-{v.shape[0]}v-{digest}"
