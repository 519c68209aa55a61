"""Batch renders of a scene with avatars: frames at a fixed or animated level of detail,
with Blender's engine (EEVEE or Cycles, through the handlers) or "exact splat" (the
Gaussians the avatars show, rendered by the splat kernel from the scene camera).

`scripts/batch_render.py` is the command line around `render_frames`.
"""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path

import bpy
import numpy as np

from archhead_addon.avatar.frame_selection import contiguous_runs
from archhead_addon.export.transform import transform_frame
from archhead_addon.io.atomic import write_bytes_atomic
from archhead_addon.splat.blender_render import render_from_blender_camera
from archhead_addon.splat.colour_space import straight_display
from archhead_addon.splat.frame import SplatFrame
from archhead_addon.synthetic.png import encode_png
from archhead_addon.threads import thread_count

from .avatar_props import is_avatar
from .avatar_session import session
from .crowd import scene_lods
from .decoding import decode_frames
from .handlers import frame_to_show
from .scene_state import blender_camera


def scene_avatars(scene) -> list:
    return [obj for obj in scene.objects if is_avatar(obj)]


@contextmanager
def fixed_lod(avatars, lod: float | None):
    """Every avatar at `lod` (overriding keys and drivers) for the duration."""
    sessions = [session(obj) for obj in avatars]
    for s in sessions:
        s.lod_override = lod
    try:
        yield
    finally:
        for s in sessions:
            s.lod_override = None


@contextmanager
def _restored(scene):
    r = scene.render
    saved = (scene.frame_start, scene.frame_end, scene.frame_step, scene.frame_current, r.filepath)
    try:
        yield
    finally:
        (scene.frame_start, scene.frame_end, scene.frame_step, frame, r.filepath) = saved
        scene.frame_set(frame)


def render_frames(
    context,
    frames,
    out_dir,
    lod: float | None = None,
    exact: bool = False,
    decode_only: bool = False,
) -> list[Path]:
    """Render `frames` into out_dir/frame_####.<ext>; returns the files written."""
    scene = context.scene
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    avatars = scene_avatars(scene)
    with fixed_lod(avatars, lod), _restored(scene):
        if decode_only:
            decode_frames(context, avatars, frames)
            return []
        if exact:
            return [_render_exact(context, frame, out_dir, avatars) for frame in frames]
        written = []
        scene.render.filepath = str(out_dir / "frame_")
        for first, last in contiguous_runs(frames):
            scene.frame_start, scene.frame_end, scene.frame_step = first, last, 1
            bpy.ops.render.render(animation=True)
            written += [Path(scene.render.frame_path(frame=f)) for f in range(first, last + 1)]
        return written


def _render_exact(context, frame: int, out_dir: Path, avatars) -> Path:
    scene = context.scene
    scene.frame_set(frame)
    depsgraph = context.evaluated_depsgraph_get()
    parts = []
    spaces = {session(obj).runtime.config.colour_space for obj in avatars}
    space = "linear" if "linear" in spaces else "display"
    if len(spaces) > 1:  # one image blends in one space: the older avatars' look changes
        print(f"ArchHead: avatars of both colour spaces in one exact render; blending {space}")
    lods = scene_lods(scene, depsgraph) or {}
    for obj in avatars:  # every avatar in Blender's world space, then one image of them all
        culled = obj.archhead_avatar.cull != "OFF"  # an exact render is a render
        lod = lods.get(obj.session_uid)
        _, splat = frame_to_show(obj, scene, depsgraph, culled=culled, lod=lod)
        parts.append(transform_frame(np.array(obj.evaluated_get(depsgraph).matrix_world), splat))
    camera = blender_camera(scene)
    raster = render_from_blender_camera(
        SplatFrame.concatenate(parts),
        camera,
        np.array(scene.camera.evaluated_get(depsgraph).matrix_world),
        np.eye(4),
        num_threads=render_threads(scene),
    )
    path = out_dir / f"frame_{frame:04d}.png"
    write_png(path, straight_display(raster.rgb, raster.alpha, space), raster.alpha)
    return path


def read_image(path) -> np.ndarray:
    """An image file as (H,W,4) float32 RGBA, top row first, read with Blender's image
    loader (to compare batch renders)."""
    image = bpy.data.images.load(str(path))
    try:
        w, h = image.size
        return np.array(image.pixels[:], np.float32).reshape(h, w, 4)[::-1]
    finally:
        bpy.data.images.remove(image)


def render_threads(scene) -> int:
    """The kernel's threads: the scene's fixed render threads (held to the cores, with a
    warning: Blender allows 1024), else 0 (every core)."""
    if scene.render.threads_mode != "FIXED":
        return 0
    return thread_count(scene.render.threads, f"scene '{scene.name}'", "render.threads")


def write_png(path: Path, straight_rgb: np.ndarray, alpha: np.ndarray) -> None:
    """An 8-bit RGBA PNG (straight alpha, as PNG defines it)."""
    rgba = np.empty((*alpha.shape, 4), np.float32)
    rgba[..., :3] = straight_rgb
    rgba[..., 3] = alpha
    pixels = np.round(np.clip(rgba, 0.0, 1.0) * 255).astype(np.uint8)
    write_bytes_atomic(path, encode_png(pixels))
