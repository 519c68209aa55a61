"""Driving clips: expression and jaw codes with a frame rate, no identity and no camera.

A dict with `exp` (T,E), `jaw` (T,3) axis-angle and `fps`, stored as `.npz`, as a pickle
(read only through the allow-list unpickler) or as a `torch.save` file (read without torch).
A clip drives an avatar that brings its own identity, so `shape` is (T,0) (`fit_to_model` pads
it, saying so); neck, eyes, global rotation and translation are zero.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..io.errors import InputError
from ..io.safe_pickle import safe_load
from ..io.torch_zip import load_torch_file, looks_like_torch_file
from .common import get, load_npz
from .sequence import Sequence
from .validation import check_frame_count

NAME = "driving-clip"


def is_driving_clip(arrays: dict) -> bool:
    return {"exp", "jaw", "fps"} <= set(arrays)


def _load_object(path: Path):
    """The stored object: npz arrays, a torch.save file, or a pickle (numpy arrays inside)."""
    if path.suffix.lower() == ".npz":
        return load_npz(path)
    if looks_like_torch_file(path):
        return load_torch_file(path)
    return safe_load(path)


def read_driving_clip(path, *, fps=None) -> Sequence:
    path = Path(path)
    if not path.is_file():
        raise InputError(path, None, "file not found")
    data = _load_object(path)
    if not isinstance(data, dict):
        raise InputError(
            path, None, f"expected a dict with exp, jaw and fps, found {type(data).__name__}"
        )
    expr = get(data, "exp", path, ("T", "E"), along="frame")
    n = len(expr)
    check_frame_count(n, path)
    jaw = get(data, "jaw", path, (n, 3), along="frame")
    stored_fps = float(get(data, "fps", path, (), (1,)).reshape(()))
    zeros = np.zeros((n, 3))
    return Sequence(
        shape=np.zeros((n, 0)),
        expr=expr,
        jaw=jaw,
        neck=zeros,
        eyes=np.zeros((n, 6)),
        rotation=zeros,
        translation=zeros,
        fps=stored_fps if fps is None else fps,
        frame_ids=np.arange(n),
        source=str(path),
        format=NAME,
    ).validate()
