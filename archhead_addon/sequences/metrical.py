"""metrical-tracker `.frame` files (Zielon/metrical-tracker, `Tracker.save_checkpoint`).

Each `checkpoint/<frame:05d>.frame` is a `torch.save` dict (numpy arrays or tensors inside),
read here without torch (io.torch_zip):

    flame:   exp (1,E), shape (1,S), jaw (1,6), eyes (1,12), eyelids (1,2), tex, sh
    camera:  R (1,6), t (1,3), fl, pp        (PyTorch3D camera; not used)
    opencv:  R (1,3,3), t (1,3), K (1,3,3)   (OpenCV world-to-camera and intrinsics)
    img_size (2,) H, W;  frame_id;  global_step

Rotations are 6D (the first two rows of the matrix, PyTorch3D layout); `eyes` holds the 6D of
FLAME joint 3 then joint 4, which become our `eyes` in that order. metrical-tracker never poses
the head: its FLAME runs with identity global and neck rotations and no translation, and the
camera carries the head pose. So `rotation`, `neck` and `translation` are zero here, and the
head pose lives in `w2c` (from `opencv` R, t) with `K` as stored. No frame rate is stored
(the tracker's config default is 25 fps).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..io.errors import InputError
from ..io.torch_zip import load_torch_file
from ..rotations import matrix_to_axis_angle, rotation_6d_to_matrix
from .cameras import w2c_from_rt
from .common import frame_number, get, numbered_files, resolve_fps
from .sequence import Sequence

NAME = "metrical-tracker"


def frame_folder(path: Path) -> Path:
    """The folder holding the .frame files: `path`, or the tracker output's `checkpoint/`."""
    checkpoint = path / "checkpoint"
    if not any(path.glob("*.frame")) and checkpoint.is_dir():
        return checkpoint
    return path


def read_metrical(path, *, fps=None) -> Sequence:
    path = Path(path)
    files = (
        [(frame_number(path), path)]
        if path.is_file()
        else numbered_files(frame_folder(path), ".frame")
    )
    frames = [_read_frame(file, number) for number, file in files]
    lacking = [
        file.name for (_, file), f in zip(files, frames, strict=True) if f["eyelids"] is None
    ]
    if 0 < len(lacking) < len(frames):
        raise InputError(
            path, "flame.eyelids", f"missing in {lacking[:8]} but present in other frames"
        )
    sizes = {f["image_size"] for f in frames}
    if len(sizes) > 1:
        raise InputError(path, "img_size", f"frames differ in image size: {sorted(sizes)}")
    n = len(frames)
    zeros = np.zeros((n, 3))
    stacked = {
        key: np.stack([f[key] for f in frames])
        for key in ("shape", "expr", "jaw", "eyes", "K", "w2c")
    }
    return Sequence(
        **stacked,
        neck=zeros,
        rotation=zeros,
        translation=zeros,
        eyelids=None if lacking else np.stack([f["eyelids"] for f in frames]),
        image_size=sizes.pop(),
        frame_ids=[number for number, _ in files],
        fps=resolve_fps(fps, path),
        source=str(path),
        format=NAME,
    ).validate()


def _section(payload, key: str, path: Path) -> dict:
    if not isinstance(payload, dict):
        raise InputError(path, None, f"expected a dict, found {type(payload).__name__}")
    section = payload.get(key)
    if not isinstance(section, dict):
        raise InputError(path, key, "missing or not a dict")
    return section


# A 6D rotation holds two rows of a rotation matrix (norm 1 each, orthogonal); Gram-Schmidt
# makes a rotation of any two independent vectors, but of a zero vector, or of two parallel
# ones, it makes no rotation at all (a singular matrix, then an arbitrary axis-angle). The
# limit is far below any tracker's values, as singular camera matrices are (cameras.py).
DEGENERATE_6D = 1e-6


def _check_6d(d6: np.ndarray, path: Path, key: str, number: int) -> None:
    """InputError naming the key and frame for a 6D rotation (rows of `d6`) whose first
    vector is (near) zero or whose second has no part orthogonal to it."""
    a1, a2 = d6[:, :3], d6[:, 3:]
    n1 = np.linalg.norm(a1, axis=1)
    b1 = a1 / np.maximum(n1, DEGENERATE_6D)[:, None]
    n2 = np.linalg.norm(a2 - (b1 * a2).sum(axis=1, keepdims=True) * b1, axis=1)
    # relative to the second vector's length: at 1e30 rounding leaves a part of 1e14
    n2 = n2 / np.maximum(np.linalg.norm(a2, axis=1), 1.0)
    for i in np.flatnonzero((n1 < DEGENERATE_6D) | (n2 < DEGENERATE_6D)):
        which = f" (rotation {i})" if len(d6) > 1 else ""
        raise InputError(
            path,
            key,
            f"degenerate 6D rotation{which} in frame {number}: {d6[i].tolist()} "
            "(a zero first vector or two parallel vectors are no rotation)",
        )


def _read_frame(path: Path, number: int) -> dict:
    payload = load_torch_file(path)
    sections = {part: _section(payload, part, path) for part in ("flame", "opencv")}

    def value(part, key, *shapes, **kw):
        return get(sections[part], key, path, *shapes, frame=number, name=f"{part}.{key}", **kw)

    def rotation(key, shape):
        d6 = value("flame", key, shape).reshape(-1, 6)
        _check_6d(d6, path, f"flame.{key}", number)
        return rotation_6d_to_matrix(d6)

    jaw = rotation("jaw", (1, 6))[0]
    eyes = rotation("eyes", (1, 12))
    eyelids = value("flame", "eyelids", (1, 2), default=None)
    size = get(payload, "img_size", path, (2,), (1, 2), frame=number).reshape(2)
    return {
        "shape": value("flame", "shape", (1, "S")).reshape(-1),
        "expr": value("flame", "exp", (1, "E")).reshape(-1),
        "jaw": matrix_to_axis_angle(jaw),
        "eyes": matrix_to_axis_angle(eyes).reshape(6),
        "eyelids": None if eyelids is None else eyelids.reshape(2),
        "K": value("opencv", "K", (1, 3, 3)).reshape(3, 3),
        "w2c": w2c_from_rt(
            value("opencv", "R", (1, 3, 3)).reshape(3, 3), value("opencv", "t", (1, 3)).reshape(3)
        ),
        "image_size": (int(size[0]), int(size[1])),
    }
