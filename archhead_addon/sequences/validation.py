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
# Training refuses codes beyond this many times their plausible magnitude: a head deformed so
# far is no face, and float32 overflows in the loss (Inf at the first step) long before 1e30
TRAIN_FACTOR = 100.0
TRAINED_CODES = ("shape", "expr", "jaw", "neck", "eyes", "rotation", "translation", "eyelids",
                 "static_offset")  # fmt: skip
MAX_IMAGE_SIDE = 1 << 16  # a larger image side is possible, but no video has one
FPS_RANGE = (1.0, 1000.0)
MAX_FRAME_ID = (1 << 31) - 1  # frame numbers are 32-bit in Blender, ffmpeg and the trackers
# Frames in one sequence: 2.4 hours at 30 fps, far beyond any tracked or driving clip. A
# sequence with cameras takes 432 bytes a frame in float64, and its checks as much again:
# without a limit a 190 kB VHAP npz of 650,000 repeated frames (deflated) cost 600 MB.
MAX_FRAMES = 1 << 18


def check_frame_count(n: int, path, key: str = "expr") -> None:
    """InputError for more than MAX_FRAMES frames: called before a reader expands them."""
    if n > MAX_FRAMES:
        raise InputError(
            path,
            key,
            f"{n} frames, above the limit of {MAX_FRAMES} for one sequence (2.4 hours at "
            "30 fps; no tracker or clip has more)",
        )


def check_values(seq) -> None:
    """Ranges of every array and of fps and image_size; the camera's matrices invertible and
    the head in front of the camera."""
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
    ids = seq.frame_ids
    if ids.size and (ids.min() < 0 or ids.max() > MAX_FRAME_ID):
        bad = int(ids.min() if ids.min() < 0 else ids.max())
        raise InputError(
            seq.source, "frame_ids", f"frame id {bad} outside 0..{MAX_FRAME_ID} (32-bit frames)"
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
    """Intrinsics of a pinhole camera (K upper triangular with last row 0 0 1, focal lengths
    > 0), an invertible rigid w2c."""
    K = seq.K
    bad = (np.abs(K[:, 2] - [0, 0, 1]) > 1e-6).any(axis=1) | (np.abs(K[:, 1, 0]) > 1e-6)
    if bad.any():
        t = int(np.argmax(bad))
        raise InputError(
            seq.source,
            "K",
            f"not pinhole intrinsics at frame index {t}: {np.round(K[t], 4).tolist()} "
            "(expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]])",
        )
    focal = np.stack([seq.K[:, 0, 0], seq.K[:, 1, 1]], axis=1)
    bad = ~(np.abs(focal) > 1e-9).all(axis=1)
    if bad.any():
        t = int(np.argmax(bad))
        raise InputError(seq.source, "K", f"zero focal length at frame index {t}: singular")
    bad = (focal < 0).any(axis=1)
    if bad.any():  # a mirrored image: no camera (Blender's included) draws one
        t = int(np.argmax(bad))
        raise InputError(
            seq.source,
            "K",
            f"negative focal length {focal[t].tolist()} at frame index {t}: "
            "a mirrored camera (focal lengths are > 0 in pixels)",
        )
    skew = np.abs(K[:, 0, 1]) > 1e-6 * np.abs(K[:, 0, 0])
    if skew.any():  # no camera ArchHead draws has one (camera.py: Blender's cannot)
        t = int(np.argmax(skew))
        raise InputError(
            seq.source,
            "K",
            f"camera skew K[0,1] = {K[t, 0, 1]:.3g} at frame index {t}: pinhole cameras "
            "without skew only (Blender's camera cannot represent one)",
        )
    rot = seq.w2c[:, :3, :3]
    det = np.linalg.det(rot)
    bad = ~(np.abs(det) > 1e-9) | (np.abs(seq.w2c[:, 3] - [0, 0, 0, 1]) > 1e-6).any(axis=1)
    if bad.any():
        t = int(np.argmax(bad))
        raise InputError(seq.source, "w2c", f"not an invertible rigid transform at frame index {t}")
    bad = det < 0
    if bad.any():  # a reflection: a mirrored camera, as a negative focal length is
        t = int(np.argmax(bad))
        raise InputError(
            seq.source,
            "w2c",
            f"rotation part with determinant {det[t]:.3g} at frame index {t}: a reflection "
            "(a mirrored camera), not a rotation",
        )
    error = np.abs(rot @ np.swapaxes(rot, 1, 2) - np.eye(3)).max(axis=(1, 2))
    if (error > 1e-3).any():
        t = int(np.argmax(error > 1e-3))
        warn_input(
            seq.source,
            "w2c",
            f"rotation part is not orthonormal at frame index {t} "
            f"(error {error[t]:.2g}): scaled or sheared cameras render distorted",
        )
    _check_in_front(seq)


def _check_in_front(seq) -> None:
    """The head (FLAME's root: `translation`, the global rotation turns about it) is in front
    of its camera on every frame: depth (camera-space z, OpenCV) > 0. A head behind the camera
    is no tracking; it renders nothing. The key blamed is `translation` where one moved the head
    there from a world origin (FLAME's rest head) not behind the camera, `w2c` otherwise (no
    translation, as where the camera carries the head pose, or the origin behind it too)."""
    root = np.einsum("tij,tj->ti", seq.w2c[:, :3, :3], seq.translation) + seq.w2c[:, :3, 3]
    depth = root[:, 2]
    bad = ~(depth > 0)
    if bad.any():
        t = int(np.argmax(bad))
        moved = np.any(seq.translation[t] != 0) and seq.w2c[t, 2, 3] >= 0
        key = "translation" if moved else "w2c"
        raise InputError(
            seq.source,
            key,
            f"the head is behind the camera at frame index {t} (frame id {seq.frame_ids[t]}, "
            f"depth {depth[t]:.3g} m): a tracked head is in front of its camera (depth > 0)",
        )


def check_trainable(seq) -> None:
    """What training cannot use although a reader accepts it (with a warning): codes beyond
    TRAIN_FACTOR x their plausible magnitude, refused at set-up rather than as a non-finite
    loss at step 1."""
    for key in TRAINED_CODES:
        value = getattr(seq, key)
        if value is None or not value.size:
            continue
        plausible, reason = PLAUSIBLE[key]
        largest = float(np.abs(value).max())
        if largest > TRAIN_FACTOR * plausible:
            where = np.unravel_index(int(np.argmax(np.abs(value))), value.shape)[0]
            raise InputError(
                seq.source,
                key,
                f"magnitude {largest:.3g} (at index {where}) is beyond what training can use, "
                f"{TRAIN_FACTOR * plausible:g} ({TRAIN_FACTOR:g} x the plausible "
                f"{plausible:g}: {reason})",
            )
