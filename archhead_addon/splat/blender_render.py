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
from .sh import degree_from_coeffs, sh_to_rgb_numpy


def blender_camera_to_opencv(camera: BlenderCamera, camera_matrix_world,
                             object_matrix_world=FLAME_TO_BLENDER):  # fmt: skip
    """(viewmat, K): viewmat maps the Gaussians' own (object) space to OpenCV camera space.
    object_matrix_world places them in Blender's world; the default is an imported head's,
    FLAME space (y up) turned z up. Any affine object matrix works (the kernel projects
    through a general 3x3)."""
    w2c = blender_matrix_world_to_w2c(camera_matrix_world, flame_world=False)
    return w2c @ np.asarray(object_matrix_world, np.float64), blender_to_intrinsics(camera)


def render_from_blender_camera(
    means, quats, log_scales, opacity_logits, colors, camera: BlenderCamera,
    camera_matrix_world, object_matrix_world=FLAME_TO_BLENDER, *,
    sh_degree: int | None = None, background=(0.0, 0.0, 0.0),
    near_plane: float = 0.01, far_plane: float = 1e10, eps2d: float = 0.3,
    antialiased: bool = False, num_threads: int = 0,
) -> kernel.Raster:  # fmt: skip
    """Render at the camera's resolution. Gaussians follow the `kernel` conventions in their
    object space; colors are (N,3) RGB or (N,K,3) SH coefficients (evaluated towards the
    camera centre in that space). Returns rgb (H,W,3) over `background`, alpha (H,W) and
    expected depth (H,W; camera z in Blender world units, 0 where empty)."""
    viewmat, K = blender_camera_to_opencv(camera, camera_matrix_world, object_matrix_world)
    colors = np.asarray(colors, dtype=np.float64)
    if colors.ndim == 3:
        degree = degree_from_coeffs(colors.shape[1]) if sh_degree is None else sh_degree
        centre = np.linalg.inv(viewmat)[:3, 3]
        means64 = kernel.check_array("means", means, (-1, 3)).astype(np.float64)
        colors = sh_to_rgb_numpy(degree, means64 - centre, colors)
    settings = kernel.RasterSettings(
        viewmat=viewmat, K=K, width=camera.resolution_x, height=camera.resolution_y,
        near_plane=near_plane, far_plane=far_plane, eps2d=eps2d, antialiased=antialiased,
        background=tuple(background), num_threads=num_threads,
    )  # fmt: skip
    return kernel.render(means, quats, log_scales, opacity_logits, colors, settings)


def render_frame_from_blender_camera(
    frame,
    camera: BlenderCamera,
    camera_matrix_world,
    object_matrix_world=FLAME_TO_BLENDER,
    **options,
) -> kernel.Raster:
    """`render_from_blender_camera` of a Gaussian container (avatar.decode_cache.SplatFrame
    or anything with its field names): the one place its fields meet the kernel's order."""
    return render_from_blender_camera(
        means=frame.means,
        quats=frame.quats,
        log_scales=frame.log_scales,
        opacity_logits=frame.opacity_logits,
        colors=frame.sh,
        camera=camera,
        camera_matrix_world=camera_matrix_world,
        object_matrix_world=object_matrix_world,
        **options,
    )
