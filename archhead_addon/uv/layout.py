"""The avatar's UV layout: a template obj, the model's own UVs, or a cached xatlas layout.

Preference: an obj the user supplies (FLAME 2020's `head_template_mesh.obj`, whose `f` lines
carry per-corner UV indices), then the model's own `vt`/`ft` (the built-in model has them),
else a deterministic xatlas layout of the template (FLAME 2023 Open ships none), cached on disk
under a hash of the mesh. The avatar mesh always has teeth: with given UVs `add_teeth` puts
their island in free UV space; on the xatlas path the teeth are part of the mesh laid out.
"""

from __future__ import annotations

import hashlib
import warnings
import zipfile
from pathlib import Path

import numpy as np

from ..flame.model import FlameModel
from ..flame.teeth import add_teeth
from ..io.atomic import save_npz_atomic
from ..io.errors import InputError
from ..paths import cache_dir

XATLAS_RESOLUTION = 1024  # atlas texels per side while packing; 4 texels of padding = 1 at S=256
XATLAS_PADDING = 4
_XATLAS_SETTINGS = f"xatlas-v1-res{XATLAS_RESOLUTION}-pad{XATLAS_PADDING}"


def layout_id(uv: np.ndarray, uv_faces: np.ndarray) -> str:
    """Names a layout in checkpoints: a hash of its float64 coordinates and int64 faces."""
    h = hashlib.sha1(np.ascontiguousarray(uv, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(uv_faces, dtype=np.int64).tobytes())
    return f"uv-{h.hexdigest()[:16]}"


def avatar_mesh(model: FlameModel, uv_obj=None, cache=None) -> FlameModel:
    """The model the avatar is built on: a UV layout attached, teeth added with their island."""
    if uv_obj is not None:
        uv, uv_faces = read_obj_uvs(uv_obj, model.faces)
        model = model.replace(uv=uv, uv_faces=uv_faces)
    if model.uv is not None:
        return add_teeth(model)
    mesh = add_teeth(model)
    uv, uv_faces = xatlas_uvs(mesh.v_template, mesh.faces, cache)
    return mesh.replace(uv=uv, uv_faces=uv_faces)


def read_obj_uvs(path, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(vt (Vt,2), ft (F,3)) from an obj whose triangles are the model's faces, in order."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, None, "UV template obj not found")
    vt, corners = [], []
    with open(path, encoding="utf-8", errors="replace") as f:
        for n, line in enumerate(f, 1):
            try:
                if line.startswith("vt "):
                    u, v = line.split()[1:3]
                    vt.append([float(u), float(v)])
                elif line.startswith("f "):
                    tokens = line.split()[1:]
                    if len(tokens) != 3 or any("/" not in t or "//" in t for t in tokens):
                        raise ValueError("expected a triangle with UV indices (f v/vt v/vt v/vt)")
                    corners.append([[int(p) for p in t.split("/")[:2]] for t in tokens])
            except ValueError as exc:
                raise InputError(path, f"line {n}", f"{exc}: {line.strip()!r}") from exc
    if not vt or not corners:
        raise InputError(path, "vt" if not vt else "f", "no UV coordinates or no faces")
    uv = np.asarray(vt, dtype=np.float64)
    idx = np.asarray(corners, dtype=np.int64) - 1  # (F,3,2): vertex, uv; obj counts from 1
    obj_faces, ft = idx[..., 0], idx[..., 1]
    if obj_faces.shape != faces.shape or not np.array_equal(obj_faces, faces):
        raise InputError(
            path,
            "f",
            f"its {len(obj_faces)} faces are not the model's "
            f"{len(faces)} faces in the same order (another topology?)",
        )
    if ft.min() < 0 or ft.max() >= len(uv):
        raise InputError(path, "f", f"UV indices outside 1..{len(uv)}")
    return uv, ft


def xatlas_uvs(verts: np.ndarray, faces: np.ndarray, cache=None) -> tuple[np.ndarray, np.ndarray]:
    """A deterministic xatlas layout of the mesh, read from / written to the on-disk cache."""
    h = hashlib.sha1(_XATLAS_SETTINGS.encode())
    h.update(np.ascontiguousarray(verts, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(faces, dtype=np.int64).tobytes())
    path = Path(cache or cache_dir()) / f"uv-xatlas-{h.hexdigest()[:20]}.npz"
    if path.is_file():
        try:
            with np.load(path, allow_pickle=False) as z:
                uv, uv_faces = z["uv"], z["uv_faces"]
            if uv_faces.shape == faces.shape:
                return uv, uv_faces
        except (zipfile.BadZipFile, OSError, ValueError, KeyError, EOFError) as exc:
            warnings.warn(f"{path}: unreadable UV cache ({exc}); generating it again", stacklevel=2)
    uv, uv_faces = _run_xatlas(verts, faces)
    save_npz_atomic(path, uv=uv, uv_faces=uv_faces)
    return uv, uv_faces


def _run_xatlas(verts: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    import xatlas

    atlas = xatlas.Atlas()
    atlas.add_mesh(
        np.ascontiguousarray(verts, dtype=np.float32), np.ascontiguousarray(faces, dtype=np.uint32)
    )
    pack = xatlas.PackOptions()
    pack.resolution, pack.padding = XATLAS_RESOLUTION, XATLAS_PADDING
    atlas.generate(xatlas.ChartOptions(), pack)
    vmapping, indices, uvs = atlas[0]
    if not np.array_equal(vmapping[indices], faces):
        raise RuntimeError("xatlas changed the face order; the UV faces would not match")
    # xatlas normalises u and v by the atlas width and height separately; undo the stretch so
    # a UV unit is the same length in both directions
    size = np.array([atlas.width, atlas.height], dtype=np.float64)
    uv = uvs.astype(np.float64) * size / size.max()
    return uv, indices.astype(np.int64)
