"""Cameras and axes: the one place where OpenCV, FLAME and Blender conventions meet.

- OpenCV camera (ours): x right, y down, z forward; world-to-camera 4x4; K in pixels with
  pixel centres at +0.5 (pixel i covers [i, i+1)).
- Blender camera: looks down its local -Z with +Y up; intrinsics as lens (mm), sensor size
  (mm) and fit, shift in units of the fitted image side, pixel aspect for fx != fy. Imported
  cameras use the horizontal fit; any fit converts back to K.
- FLAME space is y up; Blender's world is z up. Blender world = FLAME_TO_BLENDER @ FLAME world
  (+90 degrees about x), applied as the object transform of imported heads.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FLAME_TO_BLENDER = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])
CV_TO_BLENDER_CAMERA = np.diag([1.0, -1.0, -1.0, 1.0])  # flips y and z; its own inverse
SENSOR_WIDTH_MM = 36.0


@dataclass(frozen=True)
class BlenderCamera:
    """Blender camera data and render settings that decide the projection."""

    lens: float
    sensor_width: float
    shift_x: float
    shift_y: float
    resolution_x: int
    resolution_y: int
    pixel_aspect_x: float = 1.0
    pixel_aspect_y: float = 1.0
    sensor_fit: str = "HORIZONTAL"  # or "VERTICAL", "AUTO"
    sensor_height: float = 24.0


def intrinsics_to_blender(
    K, width: int, height: int, sensor_width: float = SENSOR_WIDTH_MM
) -> BlenderCamera:
    """Blender settings that project exactly like K at this resolution (no skew)."""
    K = np.asarray(K, dtype=np.float64)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if abs(K[0, 1]) > 1e-9 * fx:
        raise ValueError(f"camera skew K[0,1] = {K[0, 1]} cannot be represented in Blender")
    ycor = fx / fy  # Blender's pixel-aspect ratio y / x
    aspect_x, aspect_y = (1.0, ycor) if ycor >= 1 else (1.0 / ycor, 1.0)
    return BlenderCamera(
        lens=fx * sensor_width / width,
        sensor_width=sensor_width,
        shift_x=(width / 2 - cx) / width,
        shift_y=(cy - height / 2) * ycor / width,
        resolution_x=int(width),
        resolution_y=int(height),
        pixel_aspect_x=aspect_x,
        pixel_aspect_y=aspect_y,
    )


def blender_to_intrinsics(cam: BlenderCamera) -> np.ndarray:
    """K (3x3, pixels) of a Blender camera, as Blender computes its view plane.

    The fitted side spans the sensor size: AUTO uses sensor_width on the larger (aspect
    corrected) side, VERTICAL uses sensor_height on the height; shifts are in units of it.
    """
    width, height = cam.resolution_x, cam.resolution_y
    ycor = cam.pixel_aspect_y / cam.pixel_aspect_x
    fit, sensor = cam.sensor_fit, cam.sensor_width
    if fit == "AUTO":
        fit = (
            "HORIZONTAL"
            if cam.pixel_aspect_x * width >= cam.pixel_aspect_y * height
            else ("VERTICAL")
        )
    elif fit == "VERTICAL":
        sensor = cam.sensor_height
    elif fit != "HORIZONTAL":
        raise ValueError(f"unknown sensor_fit {cam.sensor_fit!r}")
    side = width if fit == "HORIZONTAL" else ycor * height  # the fitted side, in x pixels
    fx = cam.lens * side / sensor
    return np.array(
        [
            [fx, 0, width / 2 - cam.shift_x * side],
            [0, fx / ycor, height / 2 + cam.shift_y * side / ycor],
            [0, 0, 1],
        ]
    )


def affine_inverse(m) -> np.ndarray:
    """The inverse (float64) of a 4x4 affine matrix (last row 0, 0, 0, 1), from its 3x3 part's
    cofactors; np.linalg.LinAlgError where that part is singular. Not np.linalg.inv, for the
    cameras and objects inverted once a frame: numpy's OpenBLAS runs LAPACK on its threads even
    for a 4x4, and they kept spinning after it, slowing the next decode or splat of a render
    loop (docs/bench_decode.md)."""
    m = np.asarray(m, np.float64)
    a, t = m[:3, :3], m[:3, 3]
    cof = np.cross(a[[1, 2, 0]], a[[2, 0, 1]])  # rows r1 x r2, r2 x r0, r0 x r1
    det = float((a[0] * cof[0]).sum())
    if not det or not np.isfinite(det):
        raise np.linalg.LinAlgError(f"a singular or non-finite matrix (determinant {det})")
    out = np.eye(4)
    out[:3, :3] = cof.T / det
    out[:3, 3] = -(out[:3, :3] * t).sum(axis=1)  # element-wise: no BLAS call either
    return out


def w2c_to_blender_matrix_world(w2c, flame_world: bool = True) -> np.ndarray:
    """Blender camera object matrix_world from an OpenCV world-to-camera matrix.

    `flame_world`: the w2c maps FLAME-space (y up) points; the result is in Blender's world.
    """
    c2w = affine_inverse(w2c)
    world = FLAME_TO_BLENDER if flame_world else np.eye(4)
    return world @ c2w @ CV_TO_BLENDER_CAMERA


def blender_matrix_world_to_w2c(matrix_world, flame_world: bool = True) -> np.ndarray:
    """The inverse of `w2c_to_blender_matrix_world` (scale in matrix_world is removed)."""
    m = np.asarray(matrix_world, dtype=np.float64).copy()
    m[:3, :3] /= np.linalg.norm(m[:3, :3], axis=0)
    world = FLAME_TO_BLENDER if flame_world else np.eye(4)
    return affine_inverse(affine_inverse(world) @ m @ CV_TO_BLENDER_CAMERA)


def project(points, K, w2c) -> np.ndarray:
    """Pixel coordinates (N,2) of world points (N,3) under OpenCV K, w2c."""
    p = np.asarray(points, dtype=np.float64) @ np.asarray(w2c)[:3, :3].T + np.asarray(w2c)[:3, 3]
    uv = p @ np.asarray(K).T
    return uv[:, :2] / uv[:, 2:3]
