"""Camera conventions of the tracker formats, converted to ours: OpenCV world-to-camera + K.

OpenCV camera axes: x right, y down, z forward (into the scene). OpenGL/Blender/NeRF camera
axes: x right, y up, z backward; a camera-to-world matrix in those axes becomes an OpenCV one
by negating its y and z columns.
"""

from __future__ import annotations

import numpy as np

from ..camera import CV_TO_BLENDER_CAMERA as GL_TO_CV  # the same y/z flip, its own inverse
from ..io.errors import InputError


def w2c_from_opengl_c2w(c2w: np.ndarray, path=None, key=None) -> np.ndarray:
    """(...,4,4) camera-to-world in OpenGL camera axes -> OpenCV world-to-camera; an
    InputError naming `path` and `key` when a matrix has no inverse."""
    c2w = np.asarray(c2w, dtype=np.float64) @ GL_TO_CV
    try:
        return np.linalg.inv(c2w)
    except np.linalg.LinAlgError as exc:
        raise InputError(
            path, key, f"the camera-to-world matrix is singular (no camera pose): {exc}"
        ) from exc


def w2c_from_rt(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """OpenCV x_cam = R x_world + t, R (...,3,3), t (...,3) -> (...,4,4)."""
    R, t = np.asarray(R, dtype=np.float64), np.asarray(t, dtype=np.float64)
    w2c = np.zeros((*R.shape[:-2], 4, 4))
    w2c[..., :3, :3] = R
    w2c[..., :3, 3] = t
    w2c[..., 3, 3] = 1.0
    return w2c


def intrinsics(fx, fy, cx, cy) -> np.ndarray:
    """K (...,3,3) from focal lengths and principal point, all in pixels."""
    fx, fy, cx, cy = np.broadcast_arrays(
        *(np.asarray(v, dtype=np.float64) for v in (fx, fy, cx, cy))
    )
    K = np.zeros((*fx.shape, 3, 3))
    K[..., 0, 0], K[..., 1, 1], K[..., 0, 2], K[..., 1, 2], K[..., 2, 2] = fx, fy, cx, cy, 1.0
    return K
