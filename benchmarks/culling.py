"""What view culling saves and what it changes: a trained avatar's test frames decoded and
rendered with and without it, from the tracked camera and from a close-up.

    python benchmarks/culling.py --avatar RUN/avatar.npz --data DIR [--frames 6]
        [--size 512] [--close 0.45] [--repeats 5]

Cameras: "tracked" is each test frame's own camera; a close-up is that camera moved along its
axis until the head centre (the mean of its Gaussians) is `--close` metres away, same lens
(0.45 m: where the LOD driver's default reaches LOD 0). Per camera and level: Gaussians
decoded without culling and the share culled; decode ms without and with culling (median,
2 threads, measured in one run); the PSNR of the culled render against the unculled one.
"""

from __future__ import annotations

import argparse

from archhead_addon.timing import restart_with_threads, time_calls

LODS = (0.0, 0.5, 1.0)


def close_up(w2c, centre, distance: float):
    """w2c moved along its own axis so that `centre` (world) lies `distance` in front."""
    import numpy as np

    w2c = np.array(w2c, np.float64)
    depth = (w2c[:3, :3] @ centre + w2c[:3, 3])[2]
    w2c[2, 3] += distance - depth
    return w2c


def psnr(a, b) -> float:
    import numpy as np

    mse = float(np.mean((np.asarray(a, np.float64) - b) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(1.0 / mse)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--avatar", required=True)
    parser.add_argument("--data", required=True)
    parser.add_argument("--frames", type=int, default=6)
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument(
        "--close", default="0.45,0.3", help="close-up distances, metres (comma-separated)"
    )
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)

    import numpy as np

    from archhead_addon.avatar.culling import ViewFrustum
    from archhead_addon.avatar.runtime import AvatarRuntime
    from archhead_addon.evaluate.render import driving_codes, render_frame
    from archhead_addon.flame.model import load_model
    from archhead_addon.train.dataset import FrameDataset

    model = load_model()
    runtime = AvatarRuntime.load(args.avatar, model)
    test = FrameDataset(args.data, args.size, model, split="test", cache=False)
    picks = np.linspace(0, len(test) - 1, min(args.frames, len(test))).round().astype(int)
    frames = [test[int(i)] for i in picks]
    size = test.size
    print(f"{args.avatar}: {len(frames)} test frames of {args.data}, {size[1]}x{size[0]} px\n")
    print("| camera | l | Gaussians | culled | decode ms | culled ms | PSNR |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    cameras = ["tracked"] + [f"{float(d):g} m" for d in args.close.split(",")]
    for camera in cameras:
        for lod in LODS:
            counts, ms, scores = [], [], []
            for item in frames:
                codes = driving_codes(item["codes"])
                w2c = item["w2c"]
                if camera != "tracked":
                    full = runtime.decode(lod, **codes)
                    w2c = close_up(w2c, full.means.mean(0), float(camera.split()[0]))
                views = [None, ViewFrustum.from_camera(w2c, item["K"], size[1], size[0])]
                counts.append([len(runtime.decode(lod, view=v, **codes)) for v in views])
                ms.append(
                    [
                        time_calls(
                            lambda v=v, c=codes, level=lod: runtime.decode(level, view=v, **c),
                            args.repeats,
                            1,
                        ).median_ms
                        for v in views
                    ]
                )
                images = [
                    render_frame(
                        runtime, lod, codes, item["K"], w2c, size, test.background, view=v
                    ).rgb
                    for v in views
                ]
                scores.append(psnr(images[1], images[0]))
            n = np.mean(counts, axis=0)
            t = np.median(ms, axis=0)
            print(
                f"| {camera} | {lod:g} | {n[0]:,.0f} | {100 * (1 - n[1] / n[0]):.0f} % "
                f"| {t[0]:.1f} | {t[1]:.1f} | {min(scores):.1f} dB |"
            )
    print("\nPSNR: the lowest over the frames, culled render against unculled.")


if __name__ == "__main__":
    restart_with_threads(2)
    main()
