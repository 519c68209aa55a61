"""Render the synthetic subject: the built-in head (with teeth) along a known trajectory
(the command line is scripts/synthetic_subject.py).

Writes (folder layout of `archhead_addon.synthetic`, docs/formats.md "Synthetic subject"):

    DIR/frames/00000.png   RGB, straight colour over black; composite with the mask
    DIR/masks/00000.png    grey, the render's alpha
    DIR/tracking.npz       the exact FLAME codes, K and w2c, canonical sequence format

The trajectory (`archhead_addon.synthetic.trajectory`) is deterministic by seed; the camera
is fixed; every frame is rendered with Cycles on the CPU (albedo through the model's UVs,
key/fill/rim area lights, transparent film) from the exact FLAME forward vertices. A rerun
into the same DIR replaces the earlier subject. Never imports torch.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import time
from pathlib import Path

import bpy
import numpy as np

from archhead_addon.flame.builtin import builtin_model
from archhead_addon.flame.lbs import forward
from archhead_addon.flame.teeth import add_teeth
from archhead_addon.synthetic.subject import SubjectFolder
from archhead_addon.synthetic.trajectory import synthetic_sequence

from .head_render import add_head, add_lights, add_opencv_camera, reset_scene, set_vertices

DEFAULT_SAMPLES = 16  # denoised: 45 dB PSNR against a 128-sample render
CODES = ("shape", "expr", "jaw", "neck", "eyes", "rotation", "translation")


def _vertices(model, seq, t: int) -> np.ndarray:
    """Frame t's posed vertices (V,3), FLAME space; one frame at a time keeps memory flat."""
    return forward(model, **{k: getattr(seq, k)[t] for k in CODES})[0]


def read_render(path: Path) -> np.ndarray:
    """The 8-bit RGBA PNG Blender wrote, (H,W,4) uint8 top row first, bytes exactly as
    stored (a byte image's pixels are its stored values / 255, no colour transform)."""
    image = bpy.data.images.load(str(path))
    try:
        w, h = image.size
        pixels = np.empty(w * h * 4, dtype=np.float32)
        image.pixels.foreach_get(pixels)
    finally:
        bpy.data.images.remove(image)
    return np.round(pixels.reshape(h, w, 4)[::-1] * 255).astype(np.uint8)


@contextlib.contextmanager
def _quiet_stdout():
    """Silence Cycles' per-tile log lines (written to file descriptor 1 by C code)."""
    sys.stdout.flush()
    saved = os.dup(1)
    with open(os.devnull, "wb") as devnull:
        os.dup2(devnull.fileno(), 1)
    try:
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def render_subject(
    out,
    frames: int = 300,
    size: int = 256,
    samples: int = DEFAULT_SAMPLES,
    seed: int = 0,
    fps: float = 25.0,
    threads: int = 0,
    verbose: bool = True,
) -> SubjectFolder:
    """Render the subject into `out` (progress and a summary on stdout); returns its folder."""
    start = time.perf_counter()
    model = add_teeth(builtin_model())
    seq = synthetic_sequence(
        frames, size, seed=seed, fps=fps, n_shape=model.n_shape, n_expr=model.n_expr
    )
    folder = SubjectFolder(out)
    folder.prepare()
    folder.write_tracking(seq)

    scene = reset_scene(size, samples, transparent=True, threads=threads)
    scene.cycles.filter_width = 1.0  # sharper than the 1.5 px default; the splats are sharp
    scene.render.use_persistent_data = True  # keep textures and BVH set-up between frames
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGBA"
    scene.render.image_settings.color_depth = "8"
    head = add_head(model, _vertices(model, seq, 0))
    add_lights()
    add_opencv_camera(seq.K[0], seq.w2c[0], size, size)
    with tempfile.TemporaryDirectory(prefix="archhead_render_") as tmp:
        render_path = Path(tmp) / "render.png"
        scene.render.filepath = str(render_path)
        for t in range(frames):
            set_vertices(head, _vertices(model, seq, t))
            scene.cycles.seed = t  # fresh noise per frame, so residual noise averages out
            with _quiet_stdout():
                bpy.ops.render.render(write_still=True)
            folder.write_frame(t, read_render(render_path))
            if verbose:
                print(f"frame {t + 1}/{frames}  {time.perf_counter() - start:.1f} s", flush=True)
    if verbose:
        print(folder.summary(frames, size, samples, time.perf_counter() - start))
    return folder
