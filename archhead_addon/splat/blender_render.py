"""Exact splat image of Gaussians seen by a Blender camera (numpy only, no bpy).

The caller reads plain numbers off Blender (`archhead_addon.camera.BlenderCamera`, the
camera object's matrix_world and the avatar object's matrix_world); this module converts
them to OpenCV K / world-to-camera with `archhead_addon.camera` and renders with the C++
kernel. Image rows run top to bottom (row 0 is the top); Blender image buffers run bottom
to top, so flip rows to store one.
"""

from __future__ import annotations

import numpy as np

from ..camera import (
    FLAME_TO_BLENDER,
    BlenderCamera,
    blender_matrix_world_to_w2c,
    blender_to_intrinsics,
)
from . import kernel
from .frame import SplatFrame


def blender_camera_to_opencv(camera: BlenderCamera, camera_matrix_world,
                             object_matrix_world=FLAME_TO_BLENDER):  # fmt: skip
    """(viewmat, K): viewmat maps the Gaussians' own (object) space to OpenCV camera space.
    object_matrix_world places them in Blender's world; the default is an imported head's,
    FLAME space (y up) turned z up. Any affine object matrix works (the kernel projects
    through a general 3x3)."""
    w2c = blender_matrix_world_to_w2c(camera_matrix_world, flame_world=False)
    return w2c @ np.asarray(object_matrix_world, np.float64), blender_to_intrinsics(camera)


def render_from_blender_camera(
    frame: SplatFrame, camera: BlenderCamera, camera_matrix_world,
    object_matrix_world=FLAME_TO_BLENDER, *, background=(0.0, 0.0, 0.0),
    near_plane: float = 0.01, far_plane: float = 1e10, eps2d: float = 0.3,
    antialiased: bool = False, num_threads: int = 0,
) -> kernel.Raster:  # fmt: skip
    """Render a frame at the camera's resolution. Its Gaussians follow the `kernel`
    conventions in their object space; sh is (N,3) RGB or (N,K,3) SH coefficients (evaluated
    towards the camera centre in that space). Returns rgb (H,W,3) over `background`, alpha
    (H,W) and expected depth (H,W; camera z in Blender world units, 0 where empty)."""
    viewmat, K = blender_camera_to_opencv(camera, camera_matrix_world, object_matrix_world)
    settings = kernel.RasterSettings(
        viewmat=viewmat, K=K, width=camera.resolution_x, height=camera.resolution_y,
        near_plane=near_plane, far_plane=far_plane, eps2d=eps2d, antialiased=antialiased,
        background=tuple(background), num_threads=num_threads,
    )  # fmt: skip
    return kernel.render_frame(frame, settings)
