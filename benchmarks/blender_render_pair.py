"""Render the avatar's point instances with Cycles (and EEVEE) next to the exact splat image of
the same Gaussians from the same camera (the pictures and PSNR in docs/blender_avatar.md).

    .venv/bin/python benchmarks/blender_render_pair.py --out docs/ [--size 256]
        [--samples 64] [--eevee] [--avatar RUN/avatar.npz --sequence DIR/tracking.npz]
        [--frame 12] [--name avatar_cycles_vs_splat]

The avatar is a trained checkpoint driven by a tracked sequence (its own, for the faithfulness
check), or without --avatar an untrained one of the built-in model on the demo head. Blender's
default display settings, at LOD 0, 0.5 and 1; each row: Blender's render, the exact splat
render, and their absolute difference x4, all over the same grey. Both renders go through the
batch path (archhead_blender/batch_render.py) that the command line uses.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import bpy
import numpy as np

from archhead_addon.io.atomic import write_bytes_atomic
from archhead_addon.sequences import write_canonical
from archhead_addon.sequences.demo import demo_sequence
from archhead_addon.synthetic.png import encode_png
from archhead_blender import api

REPO = Path(__file__).resolve().parents[1]
FRAME = 12
GREY = 0.12


def _over_grey(rgba: np.ndarray) -> np.ndarray:
    return rgba[..., :3] * rgba[..., 3:] + GREY * (1 - rgba[..., 3:])


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(10 * np.log10(1.0 / np.mean((a - b) ** 2)))


def main(argv) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=REPO / "docs")
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--samples", type=int, default=64)
    parser.add_argument("--eevee", action="store_true", help="add EEVEE (slow without a GPU)")
    parser.add_argument("--avatar", type=Path, help="trained avatar (default: untrained)")
    parser.add_argument("--sequence", type=Path, help="tracked sequence that drives it")
    parser.add_argument("--frame", type=int, default=FRAME)
    parser.add_argument("--name", help="picture name (.png added)")
    args = parser.parse_args(argv)

    import torch

    from archhead_addon.avatar.checkpoint import save_avatar
    from archhead_addon.avatar.model import ArchHeadAvatar
    from archhead_addon.flame import load_model

    api.enable_addon()
    folder = api.scratch_folder("archhead_pair_")
    avatar = args.avatar
    if avatar is None:
        torch.manual_seed(0)
        avatar = folder / "avatar.npz"
        save_avatar(avatar, ArchHeadAvatar.create(load_model()))
    sequence = args.sequence
    if sequence is None:
        sequence = folder / "demo.npz"
        write_canonical(
            demo_sequence(frames=args.frame + 1, image_size=(args.size, args.size)), sequence
        )
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.archhead.import_sequence(filepath=str(sequence))
    head = bpy.context.view_layer.objects.active
    bpy.ops.archhead.load_avatar(filepath=str(avatar))
    scene = bpy.context.scene
    size = scene.render
    scale = args.size / max(size.resolution_x, size.resolution_y)
    size.resolution_x, size.resolution_y = (
        round(size.resolution_x * scale),
        round(size.resolution_y * scale),
    )
    size.resolution_percentage = 100
    print(f"{avatar} on {head.name}, frame {args.frame}, {size.resolution_x}x{size.resolution_y}")
    r = scene.render
    r.film_transparent, r.threads_mode, r.threads = True, "FIXED", 2
    r.image_settings.file_format, r.image_settings.color_mode = "PNG", "RGBA"
    r.image_settings.color_depth = "8"
    scene.view_settings.view_transform = "Standard"
    scene.cycles.samples, scene.cycles.use_denoising = args.samples, False
    scene.cycles.use_adaptive_sampling = False
    scene.eevee.taa_render_samples = args.samples

    engines = ["CYCLES"] + (["BLENDER_EEVEE"] if args.eevee else [])
    rows = []
    for lod in (0.0, 0.5, 1.0):
        watch = api.Stopwatch()
        (exact_path,) = api.render_frames(
            bpy.context, [args.frame], folder / f"exact_{lod:g}", lod=lod, exact=True
        )
        exact = _over_grey(api.read_image(exact_path))
        print(f"LOD {lod:g}: exact splat {watch.seconds:.1f} s")
        for engine in engines:
            r.engine = engine
            watch = api.Stopwatch()
            (path,) = api.render_frames(
                bpy.context, [args.frame], folder / f"{engine}_{lod:g}", lod=lod
            )
            image = _over_grey(api.read_image(path))
            print(
                f"LOD {lod:g}: {engine} {watch.seconds:.1f} s, "
                f"PSNR against the exact splat {psnr(image, exact):.2f} dB"
            )
            rows.append(
                np.concatenate([image, exact, np.clip(4 * np.abs(image - exact), 0, 1)], axis=1)
            )
    picture = np.concatenate(rows, axis=0)
    name = args.name or (
        "avatar_cycles_vs_splat" if len(engines) == 1 else "avatar_engines_vs_splat"
    )
    name += ".png"
    write_bytes_atomic(args.out / name, encode_png(np.round(picture * 255).astype(np.uint8)))
    print(f"wrote {args.out / name}")


if __name__ == "__main__":
    main(api.script_args(sys.argv))
