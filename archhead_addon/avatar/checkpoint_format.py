"""The avatar checkpoint: one npz that numpy alone reads (no pickles), written atomically.

Keys (format version 1):
  format          "archhead-avatar"
  format_version  int64, 1
  config          the AvatarConfig as JSON
  model_id        id of the FLAME model the avatar was trained on (before teeth)
  uv_layout_id    hash of uv / uv_faces (see uv.layout.layout_id)
  uv, uv_faces    the layout of the avatar mesh (model + teeth), so no UV generator is needed
                  where the avatar is used (Blender's Python has no xatlas)
  identity_shape  (n_shape,) the avatar's FLAME identity code
  identity_offset optional (V,3) metres: the tracking's per-vertex static offset of the
                  identity, V the vertices of the model before teeth (identity.py)
  checksum        sha256 of the other keys (io/checksum.py); files from before it lack it
  param/<name>    float32, every learned array of config.parameter_shapes: the feature field
                  (param/features.<S>), the mapping network and the decoder
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..flame.model import FlameModel, load_model
from ..flame.teeth import add_teeth
from ..io.atomic import save_npz_atomic
from ..io.checksum import verify, with_checksum
from ..io.errors import InputError
from ..io.npz import read_npz
from ..io.schema import check_range
from ..uv.layout import layout_id
from .config import AvatarConfig, parameter_shapes

FORMAT = "archhead-avatar"
FORMAT_VERSION = 1


@dataclass
class AvatarCheckpoint:
    config: AvatarConfig
    model_id: str
    uv: np.ndarray
    uv_faces: np.ndarray
    identity_shape: np.ndarray
    params: dict[str, np.ndarray]
    identity_offset: np.ndarray | None = None

    @property
    def uv_layout_id(self) -> str:
        return layout_id(self.uv, self.uv_faces)


def write_checkpoint(path, ckpt: AvatarCheckpoint) -> None:
    _check_params(path, ckpt.config, ckpt.params)
    arrays = {
        "format": np.str_(FORMAT),
        "format_version": np.int64(FORMAT_VERSION),
        "config": np.str_(ckpt.config.to_json()),
        "model_id": np.str_(ckpt.model_id),
        "uv_layout_id": np.str_(ckpt.uv_layout_id),
        "uv": np.asarray(ckpt.uv, np.float64),
        "uv_faces": np.asarray(ckpt.uv_faces, np.int64),
        "identity_shape": np.asarray(ckpt.identity_shape, np.float32),
    }
    if ckpt.identity_offset is not None:
        arrays["identity_offset"] = np.asarray(ckpt.identity_offset, np.float32)
    arrays.update({f"param/{k}": np.asarray(v, np.float32) for k, v in ckpt.params.items()})
    save_npz_atomic(path, **with_checksum(arrays))


def read_checkpoint(path) -> AvatarCheckpoint:
    """Read and validate; any problem is an InputError naming the file, the key and what.
    The checksum is checked last, so a value that is wrong in a way the checks name (NaN,
    a shape) is reported as that."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, None, "avatar checkpoint not found")
    arrays = read_npz(path, what="checkpoint (truncated or not an npz)")

    def get(key, kind=None):
        if key not in arrays:
            raise InputError(path, key, "missing")
        value = arrays[key]
        if kind is not None and (value.dtype.kind not in kind or (kind == "U" and value.ndim)):
            raise InputError(path, key, f"unexpected {value.dtype} {value.shape}")
        return value

    if "format" not in arrays or str(get("format")) != FORMAT:
        raise InputError(path, "format", "not an ArchHead avatar checkpoint")
    version = get("format_version")
    if version.shape != () or version.dtype.kind not in "iu" or version != FORMAT_VERSION:
        raise InputError(
            path,
            "format_version",
            f"format version {version}; this ArchHead reads version {FORMAT_VERSION}",
        )
    try:
        config = AvatarConfig.from_json(str(get("config", "U")))
    except (ValueError, TypeError, RecursionError) as exc:
        raise InputError(path, "config", f"invalid: {exc}") from exc
    params = {k[len("param/") :]: v for k, v in arrays.items() if k.startswith("param/")}
    ckpt = AvatarCheckpoint(
        config=config,
        model_id=str(get("model_id", "U")),
        uv=get("uv", "f"),
        uv_faces=get("uv_faces", "iu"),
        identity_shape=get("identity_shape", "f"),
        params=params,
        identity_offset=get("identity_offset", "f") if "identity_offset" in arrays else None,
    )
    stored_id = str(get("uv_layout_id", "U"))
    _check_params(path, config, params)
    _check_layout(path, ckpt, stored_id)
    check_range(ckpt.identity_shape, path, "identity_shape", plausible=20.0, reason=_SIGMAS)
    if ckpt.identity_shape.ndim != 1:
        raise InputError(path, "identity_shape", "expected a finite 1-D array")
    offset = ckpt.identity_offset
    if offset is not None:
        if offset.ndim != 2 or offset.shape[1] != 3:
            raise InputError(path, "identity_offset", f"expected (V, 3), found {offset.shape}")
        check_range(offset, path, "identity_offset", plausible=0.05, reason=_METRES)
    verify(arrays, path)
    return ckpt


_SIGMAS = "FLAME coefficients are in standard deviations"
_METRES = "a static offset is metres on a head some 0.2 m across"


def _check_layout(path, ckpt: AvatarCheckpoint, stored_id: str) -> None:
    if (
        ckpt.uv.ndim != 2
        or ckpt.uv.shape[1] != 2
        or ckpt.uv_faces.ndim != 2
        or ckpt.uv_faces.shape[1] != 3
        or ckpt.uv_faces.min(initial=0) < 0
        or ckpt.uv_faces.max(initial=0) >= len(ckpt.uv)
    ):
        raise InputError(path, "uv_faces", "not a (F,3) index array into uv (Vt,2)")
    if not (np.isfinite(ckpt.uv).all() and (ckpt.uv >= 0).all() and (ckpt.uv <= 1).all()):
        raise InputError(path, "uv", "UV coordinates must be finite and within [0, 1]")
    if ckpt.uv_layout_id != stored_id:
        raise InputError(
            path,
            "uv_layout_id",
            f"{stored_id} does not match the stored layout "
            f"({ckpt.uv_layout_id}); the file is damaged",
        )


def _check_params(path, config: AvatarConfig, params: dict) -> None:
    want = parameter_shapes(config)
    extra = sorted(set(params) - set(want))
    if extra:
        raise InputError(path, f"param/{extra[0]}", "not a parameter of this configuration")
    for name, shape in want.items():
        key = f"param/{name}"
        if name not in params:
            raise InputError(path, key, "missing")
        value = params[name]
        if tuple(value.shape) != shape:
            raise InputError(path, key, f"shape {tuple(value.shape)}, the config needs {shape}")
        if value.dtype.kind != "f":
            raise InputError(path, key, f"expected floats, found {value.dtype}")
        if not np.isfinite(value).all():
            raise InputError(path, key, "contains NaN or Inf")


def checkpoint_mesh(ckpt: AvatarCheckpoint, flame=None, path=None) -> FlameModel:
    """The avatar mesh: the FLAME model (a FlameModel, a file, or None = built-in) the avatar
    was trained on, with teeth, carrying the checkpoint's UV layout."""
    base = flame if isinstance(flame, FlameModel) else load_model(flame)
    if base.model_id != ckpt.model_id:
        raise InputError(
            path,
            "model_id",
            f"the avatar was trained on '{ckpt.model_id}', "
            f"the FLAME model given is '{base.model_id}'",
        )
    mesh = add_teeth(base)
    if len(ckpt.uv_faces) != len(mesh.faces):
        raise InputError(
            path, "uv_faces", f"{len(ckpt.uv_faces)} UV faces for a mesh of {len(mesh.faces)} faces"
        )
    if ckpt.identity_offset is not None and len(ckpt.identity_offset) != base.n_verts:
        raise InputError(
            path,
            "identity_offset",
            f"{len(ckpt.identity_offset)} vertices, the model has {base.n_verts}",
        )
    if len(ckpt.identity_shape) > base.n_shape:
        raise InputError(
            path,
            "identity_shape",
            f"{len(ckpt.identity_shape)} values, the model has {base.n_shape} identity components",
        )
    return mesh.replace(uv=ckpt.uv, uv_faces=ckpt.uv_faces)
