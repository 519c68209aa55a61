"""ArchHead's own sequence file: one `.npz` (numpy only, no pickles), written atomically.

Keys (T frames; float64 unless noted; rotations axis-angle in radians; FLAME space, metres):

    format_version  int64 scalar     1; a reader refuses versions newer than it knows
    fps             float64 scalar   frames per second
    frame_ids       (T,) int64       strictly increasing source frame numbers
    shape           (T,S)            identity coefficients (repeated when constant)
    expr            (T,E)            expression coefficients
    jaw, neck       (T,3)            joint rotations
    eyes            (T,6)            left eye (FLAME joint 3) then right eye (joint 4)
    rotation        (T,3)            global rotation about the root joint
    translation     (T,3)            metres
    source_format   str scalar       the format the sequence was converted from
    source_path     str scalar       the path it was converted from
  optional:
    K               (T,3,3)          intrinsics in pixels, pixel centres at +0.5
    w2c             (T,4,4)          OpenCV world-to-camera (x right, y down, z forward)
    image_size      (2,) int64       H, W in pixels
    static_offset   (V,3)            per-vertex template offsets, metres (VHAP)
    eyelids         (T,2)            eyelid blendshape weights, left then right

K and w2c come together or not at all. Unknown keys are ignored with a warning.
"""

from __future__ import annotations

import numpy as np

from ..io.atomic import save_npz_atomic
from ..io.errors import InputError, warn_input
from .common import get, load_npz
from .sequence import OPTIONAL, PER_FRAME, Sequence

FORMAT_VERSION = 1
NAME = "canonical"
_META = (
    "format_version",
    "fps",
    "frame_ids",
    "image_size",
    "source_format",
    "source_path",
    "static_offset",
)


def write_canonical(seq: Sequence, path) -> None:
    """Validate `seq` and write it to `path` atomically (the name is kept as given)."""
    seq.validate()
    arrays = {name: getattr(seq, name) for name in PER_FRAME if getattr(seq, name) is not None}
    if seq.static_offset is not None:
        arrays["static_offset"] = seq.static_offset
    if seq.image_size is not None:
        arrays["image_size"] = np.asarray(seq.image_size, dtype=np.int64)
    save_npz_atomic(
        path,
        format_version=np.int64(FORMAT_VERSION),
        fps=np.float64(seq.fps),
        frame_ids=seq.frame_ids,
        source_format=np.str_(seq.format),
        source_path=np.str_(seq.source),
        **arrays,
    )


def is_canonical(arrays: dict) -> bool:
    return "format_version" in arrays


def read_canonical(path, *, fps=None) -> Sequence:
    """The sequence in `path`; `fps` overrides the stored frame rate."""
    arrays = load_npz(path)
    if "format_version" not in arrays:
        raise InputError(path, "format_version", "missing: not an ArchHead sequence file")
    version = arrays["format_version"]
    if version.shape != () or version.dtype.kind not in "iu":
        raise InputError(
            path,
            "format_version",
            f"expected an integer scalar, found {version.dtype} {version.shape}",
        )
    if int(version) < 1:
        raise InputError(path, "format_version", f"version {int(version)}: versions start at 1")
    if int(version) > FORMAT_VERSION:
        raise InputError(
            path,
            "format_version",
            f"version {int(version)} is newer than this reader ({FORMAT_VERSION}); update ArchHead",
        )
    unknown = sorted(set(arrays) - set(PER_FRAME) - set(_META))
    if unknown:
        warn_input(path, None, f"unknown keys ignored: {', '.join(unknown)}")
    codes = {
        name: get(arrays, name, path, ("T",) + (width or ("N",)), along="frame")
        for name, width in PER_FRAME.items()
        if name in arrays or name not in OPTIONAL
    }
    size = get(arrays, "image_size", path, (2,), default=None)
    frame_ids = arrays.get("frame_ids")
    if frame_ids is None or frame_ids.dtype.kind not in "iu":
        raise InputError(path, "frame_ids", "missing or not integers")
    return Sequence(
        **codes,
        fps=float(get(arrays, "fps", path, ())) if fps is None else fps,
        frame_ids=frame_ids,
        image_size=None if size is None else tuple(int(v) for v in size),
        static_offset=get(arrays, "static_offset", path, ("V", 3), along="vertex", default=None),
        source=str(path),
        format=NAME,
    ).validate()
