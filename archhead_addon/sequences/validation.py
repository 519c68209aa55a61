"""Value ranges of a Sequence: what no tracker writes is refused, what is possible but
implausible (a unit or format mix-up, usually) is read with one InputWarning per key."""

from __future__ import annotations

import numpy as np

from ..io.errors import InputError, warn_input
from ..io.schema import check_range

# key: (plausible magnitude, why)
PLAUSIBLE = {
    "shape": (20.0, "FLAME coefficients are in standard deviations; trackers stay within ±5"),
    "expr": (20.0, "FLAME coefficients are in standard deviations; trackers stay within ±5"),
    "jaw": (2 * np.pi, "axis-angle rotations beyond one turn"),
    "neck": (2 * np.pi, "axis-angle rotations beyond one turn"),
    "eyes": (2 * np.pi, "axis-angle rotations beyond one turn"),
    "rotation": (2 * np.pi, "axis-angle rotations beyond one turn"),
    "translation": (100.0, "metres; a head 100 m away"),
    "eyelids": (10.0, "blendshape weights near [0, 1]"),
    "static_offset": (0.5, "metres added to a head's vertices"),
    "K": (1e7, "pixels"),
    "w2c": (1e4, "metres"),
}
MAX_IMAGE_SIDE = 1 << 16  # a larger image side is possible, but no video has one
FPS_RANGE = (1.0, 1000.0)


def check_values(seq) -> None:
    """Ranges of every array and of fps and image_size; the camera's matrices invertible."""
    for key, (plausible, reason) in PLAUSIBLE.items():
        value = getattr(seq, key)
        if value is not None:
            check_range(value, seq.source, key, plausible=plausible, reason=reason)
    if not FPS_RANGE[0] <= seq.fps <= FPS_RANGE[1]:
        warn_input(
            seq.source,
            "fps",
            f"{seq.fps:g} frames per second is outside the plausible "
            f"{FPS_RANGE[0]:g}..{FPS_RANGE[1]:g}",
        )
    if seq.image_size is not None:
        if max(seq.image_size) >= 1 << 63:
            raise InputError(seq.source, "image_size", f"{seq.image_size} is beyond int64")
        if max(seq.image_size) > MAX_IMAGE_SIDE:
            warn_input(
                seq.source,
                "image_size",
                f"{seq.image_size} pixels is larger than the plausible {MAX_IMAGE_SIDE} per side",
            )
    if seq.K is not None:
        _check_camera(seq)


def _check_camera(seq) -> None:
    focal = np.stack([seq.K[:, 0, 0], seq.K[:, 1, 1]], axis=1)
    bad = ~(np.abs(focal) > 1e-9).all(axis=1)
    if bad.any():
        t = int(np.argmax(bad))
        raise InputError(seq.source, "K", f"zero focal length at frame index {t}: singular")
    rot = seq.w2c[:, :3, :3]
    det = np.linalg.det(rot)
    bad = ~(np.abs(det) > 1e-9) | (np.abs(seq.w2c[:, 3] - [0, 0, 0, 1]) > 1e-6).any(axis=1)
    if bad.any():
        t = int(np.argmax(bad))
        raise InputError(seq.source, "w2c", f"not an invertible rigid transform at frame index {t}")
    error = np.abs(rot @ np.swapaxes(rot, 1, 2) - np.eye(3)).max(axis=(1, 2))
    if (error > 1e-3).any():
        t = int(np.argmax(error > 1e-3))
        warn_input(
            seq.source,
            "w2c",
            f"rotation part is not orthonormal at frame index {t} "
            f"(error {error[t]:.2g}): scaled or sheared cameras render distorted",
        )
