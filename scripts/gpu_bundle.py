"""Pack what a borrowed GPU machine needs beside a checkout to run the GPU check
(docs/gpu.md), small enough to send:

    .venv/bin/python scripts/gpu_bundle.py --data out/real_hn [--run out/runs/RUN]
        [--out .gpu] [--quality 95]

FOLDER gets:
- site/: gsplat's sources (its CUDA kernels build there on first use; the bundled GLM's
  documents and tests left out) and stlpips_pytorch with only the AlexNet weights training
  uses: a machine with torch and numpy needs nothing else;
- data/NAME: the tracked folder, its frames as JPEG (white where the head-and-neck mask is 0,
  which training and evaluation composite away) and its masks and regions re-compressed
  (masks_person/ stays behind: the GPU check trains and scores on head and neck); prints how far
  the JPEG frames lie from the originals inside the mask (PSNR), which bounds what the
  compression moves a score;
- runs/NAME: a finished run's avatar.npz, checkpoint.json and config.json (`--run`), for
  `gpu_check.py --score`;
- run.sh: the check, run from the checkout's root (`bash FOLDER/run.sh`), with its results
  under $OUT (default FOLDER/results).
"""

from __future__ import annotations

import argparse
import importlib.util
import shutil
from pathlib import Path

import numpy as np
from PIL import Image

RUN_SH = """#!/bin/bash
# The GPU check on this bundle (scripts/gpu_bundle.py); run from the checkout's root.
B=$(cd {bundle} && pwd)
OUT=${{OUT:-$B/results}}; mkdir -p "$OUT"
export PYTHONPATH=$B/site:$PWD PYTHONUNBUFFERED=1
# gsplat's build: 9.0 is Hopper (H100, H200); set TORCH_CUDA_ARCH_LIST for another card
export MAX_JOBS=${{MAX_JOBS:-$(nproc)}} TORCH_CUDA_ARCH_LIST=${{TORCH_CUDA_ARCH_LIST:-9.0}}
nvidia-smi -L
python3 benchmarks/perceptual_batch.py --device cuda --size 512 --renders 5 --rounds 10 \\
    | tee "$OUT/lpips_batch.txt"
timeout ${{GC_S:-470}} python3 benchmarks/gpu_check.py --data $B/data/{data} \\
    --out /tmp/gpu_check/gpu_check.md {score}--minutes ${{MIN:-0}} > "$OUT/gpu_check.log" 2>&1
echo "gpu_check: exit $?"
cp /tmp/gpu_check/gpu_check.md "$OUT/" && cat "$OUT/gpu_check.md"
"""


def _package(name: str) -> Path:
    spec = importlib.util.find_spec(name)
    if spec is None or spec.origin is None:
        raise SystemExit(f"gpu_bundle: {name} is not installed in this Python (make setup)")
    return Path(spec.origin).parent


def pack_site(site: Path) -> None:
    ignore = shutil.ignore_patterns("__pycache__")
    gsplat = site / "gsplat"
    shutil.copytree(_package("gsplat"), gsplat, ignore=ignore)
    for extra in ("doc", "test"):
        shutil.rmtree(gsplat / "cuda/csrc/third_party/glm" / extra, ignore_errors=True)
    stlpips = site / "stlpips_pytorch"
    shutil.copytree(_package("stlpips_pytorch"), stlpips, ignore=ignore)
    for weights in stlpips.glob("weights/*/*.pth"):
        if not weights.name.startswith("alex"):
            weights.unlink()


def pack_data(data: Path, out: Path, quality: int) -> float:
    """The tracked folder with JPEG frames; PSNR of the JPEG frames inside the mask."""
    (out / "frames").mkdir(parents=True)
    shutil.copyfile(data / "tracking.npz", out / "tracking.npz")
    for masks in ("masks", "regions"):  # regions/: what `"cut": "region"` runs cut to
        if (data / masks).is_dir():
            shutil.copytree(data / masks, out / masks)
            for mask in (out / masks).glob("*.png"):
                Image.open(mask).save(mask, optimize=True)
    squared, pixels = 0.0, 0
    for frame in sorted((data / "frames").glob("*.png")):
        rgb = np.asarray(Image.open(frame).convert("RGB")).copy()
        inside = np.asarray(Image.open(data / "masks" / frame.name)) > 0
        rgb[~inside] = 255
        jpeg = out / "frames" / f"{frame.stem}.jpg"
        Image.fromarray(rgb).save(jpeg, quality=quality, subsampling=0)
        back = np.asarray(Image.open(jpeg)).astype(np.float64)
        squared += float((((back - rgb) / 255) ** 2)[inside].sum())
        pixels += int(inside.sum()) * 3
    return 10 * np.log10(pixels / max(squared, 1e-12))


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, required=True, help="a tracked folder (frames as PNG)")
    p.add_argument("--run", type=Path, help="a finished run to score on the GPU too")
    p.add_argument("--out", type=Path, default=Path(".gpu"), help="the bundle folder (new)")
    p.add_argument("--quality", type=int, default=95, help="JPEG quality of the frames")
    args = p.parse_args(argv)
    if args.out.exists():
        raise SystemExit(f"gpu_bundle: {args.out} exists; remove it or name another --out")
    for need in ("frames", "masks", "tracking.npz"):
        if not (args.data / need).exists():
            raise SystemExit(f"gpu_bundle: {args.data / need} is missing (a `track` folder has it)")
    pack_site(args.out / "site")
    psnr = pack_data(args.data, args.out / "data" / args.data.name, args.quality)
    score = ""
    if args.run is not None:
        runs = args.out / "runs" / args.run.name
        runs.mkdir(parents=True)
        for name in ("avatar.npz", "checkpoint.json", "config.json"):
            shutil.copyfile(args.run / name, runs / name)
        score = f"--score $B/runs/{args.run.name} "
    script = RUN_SH.format(bundle=args.out.as_posix(), data=args.data.name, score=score)
    (args.out / "run.sh").write_text(script)
    size = sum(f.stat().st_size for f in args.out.rglob("*") if f.is_file()) / 2**20
    print(f"{args.out}: {size:.1f} MiB; JPEG frames {psnr:.1f} dB from the PNG inside the mask")
    print(f"on the GPU machine, from the checkout's root: bash {args.out}/run.sh")


if __name__ == "__main__":
    main()
