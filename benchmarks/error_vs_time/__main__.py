"""The error-against-run-time report of a trained avatar:

    python -m benchmarks.error_vs_time [--avatar out/run_cpu/avatar.npz]
        [--data out/subject256] [--out out/report] [--docs DIR] [--step 0.05]
        [--test-frames N] [--holdout H] [--mask M] [--cut C] [--no-blender]
        [--ablations [--steps N] [--ablation-config F]]

(from the checkout's root).

Per level of detail (steps of --step): Gaussians, numpy decode ms (fp32, fp16), the splat
kernel's ms at 512², Blender's update ms for a LOD change (benchmarks/blender_lod.py --sweep,
in a child process through the bpy module), test L1 / PSNR / SSIM / ST-LPIPS; the error-against-
run-time curve; the image change between neighbouring levels; the LOD 1 : LOD 0 ratios beside
the paper's; the stability sweep; with --ablations, table 4's variants trained by the project's
training command with the same config and the same steps each (--steps, default the config's
total). Writes OUT/report.md, OUT/error_vs_time.png and OUT/lod_smoothness.png; --docs copies
them there (the report as bench_report.md).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from archhead_addon.io.atomic import write_bytes_atomic
from archhead_addon.io.cli import run_command
from archhead_addon.timing import Stopwatch
from archhead_addon.train.config import CUTS, HOLDOUTS, MASKS

BLENDER_LOD = Path(__file__).resolve().parents[1] / "blender_lod.py"

FIGURES = ("error_vs_time.png", "lod_smoothness.png")
DOCS_REPORT = "bench_report.md"


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.error_vs_time", description=__doc__.split("\n\n")[0]
    )
    p.add_argument(
        "--avatar",
        type=Path,
        default=Path("out/run_cpu/avatar.npz"),
        help="trained avatar (default: the CPU run's, out/run_cpu/avatar.npz)",
    )
    p.add_argument(
        "--data",
        type=Path,
        default=Path("out/subject256"),
        help="the data folder it trained on (default: out/subject256)",
    )
    p.add_argument("--out", type=Path, default=Path("out/report"))
    p.add_argument(
        "--docs",
        type=Path,
        help="also copy the report (as bench_report.md) and its figures into this folder",
    )
    p.add_argument("--step", type=float, default=0.05, help="LOD step (1 / step an integer)")
    p.add_argument("--test-frames", type=int, help="use only the first N test frames")
    p.add_argument("--resolution", type=int, help="image size (default: the training run's)")
    p.add_argument(
        "--holdout",
        choices=HOLDOUTS,
        help="the run's held-out frames (default: its config.json's, else the last 10 %%)",
    )
    p.add_argument("--mask", choices=MASKS, help="which masks cut the truth (default: the run's)")
    p.add_argument("--cut", choices=CUTS, help="what the renders are cut to (default: the run's)")
    p.add_argument("--repeats", type=int, default=3, help="timings: median of this many")
    p.add_argument("--no-blender", action="store_true", help="leave out Blender's update ms")
    p.add_argument(
        "--ablations",
        action="store_true",
        help="train and evaluate table 4's "
        "variants (no feature map, single maps 64 / 128 / 256, and the full field)",
    )
    p.add_argument(
        "--steps", type=int, help="training steps of every variant (default: the config's total)"
    )
    p.add_argument(
        "--ablation-config",
        default="cpu",
        help="their common training config (file or preset; default: cpu)",
    )
    args = p.parse_args(argv)
    if not 0 < args.step <= 1 or abs(1 / args.step - round(1 / args.step)) > 1e-9:
        p.error("--step must divide 1, e.g. 0.05")
    return args


def blender_update_ms(avatar: Path, step: float, repeats: int) -> dict[float, float]:
    """{l: median ms of a LOD change in Blender} from benchmarks/blender_lod.py --sweep (in a
    child process: the bpy module)."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "lod.json"
        subprocess.run(
            [
                sys.executable,
                str(BLENDER_LOD),
                "--checkpoint",
                str(avatar.resolve()),
                "--sweep",
                str(step),
                "--json",
                str(out),
                "--repeats",
                str(repeats),
            ],
            check=True,
            stdout=subprocess.DEVNULL,
        )
        return {row["lod"]: row["update_ms"] for row in json.loads(out.read_text())}


def run(args) -> Path:
    import torch

    from archhead_addon.avatar.runtime import AvatarRuntime
    from archhead_addon.evaluate.__main__ import run_cut, run_holdout, run_mask, run_resolution
    from archhead_addon.evaluate.lods import evaluate_lods
    from archhead_addon.flame.model import load_model
    from archhead_addon.train.config import TrainConfig
    from archhead_addon.train.dataset import FrameDataset
    from archhead_addon.train.perceptual import ShiftTolerantLPIPS

    from . import ablations, report
    from .stability import stability_sweep
    from .sweep import lod_steps, measure_lods, smoothness

    watch = Stopwatch()
    model = load_model()
    runtime = AvatarRuntime.load(args.avatar, model)
    test = FrameDataset(
        args.data,
        run_resolution(args),
        model,
        split="test",
        holdout=run_holdout(args),
        mask=run_mask(args),
    )
    cut = run_cut(args) == "region"
    count = len(test) if args.test_frames is None else min(args.test_frames, len(test))
    frames = [test[i] for i in range(count)]
    perceptual = ShiftTolerantLPIPS()
    lods = lod_steps(args.step)
    rows, images = measure_lods(
        runtime, frames, test.size, test.background, perceptual, lods, args.repeats, cut
    )
    update = {} if args.no_blender else blender_update_ms(args.avatar, args.step, args.repeats)
    pairs = smoothness(images)
    stability = stability_sweep(runtime, frames[0], test.size, test.background)

    title = (
        f"{args.avatar}: {count} test frames of {args.data.name}, {test.size[1]}x{test.size[0]} px"
    )
    args.out.mkdir(parents=True, exist_ok=True)
    report.plot_error_vs_time(args.out / FIGURES[0], rows, title)
    report.plot_smoothness(args.out / FIGURES[1], pairs, title)
    smooth_table, largest = report.smoothness_table(pairs)
    worst = max(stability, key=lambda r: r.max_abs["means"])
    non_finite = sum(r.non_finite for r in stability)
    sections = [
        f"# ArchHead: error against run time\n\n{title}. Machine: {os.cpu_count()} CPUs "
        f"({platform.processor() or platform.machine()}), torch {torch.__version__}, "
        f"{torch.get_num_threads()} threads. Command: `python -m benchmarks.error_vs_time "
        f"{' '.join(args.argv)}`.",
        "## Per level of detail\n\nDecode: the numpy runtime (Blender's path), median over "
        "the test frames decoded one after another. Kernel: SH colour + the C++ splat at "
        f"{report.KERNEL_SIZE}², median of {args.repeats}. Blender update: setting the "
        "avatar's level of detail to a new value through an evaluated depsgraph (handler, "
        "decode, point writes, Geometry Nodes; `benchmarks/blender_lod.py --sweep`). Frame = "
        "fp32 decode + kernel. Errors: fp32 on the test frames at the training resolution."
        "\n\n" + report.lod_table(rows, update),
        f"![error against run time]({FIGURES[0]})",
        "## LOD 1 against LOD 0, beside the paper\n\n" + report.ratio_table(rows),
        "## LOD smoothness\n\nThe first test frame at neighbouring levels (fp32), mean "
        f"absolute difference.\n\n{largest}\n\n{smooth_table}\n\n![smoothness]({FIGURES[1]})",
        "## Stability sweep\n\nThe first test frame with one thing changed; image change "
        f"against its unchanged render (for the cameras: the same frame from the test camera). "
        "Log scales are clamped and quaternions normalised by construction, so the table shows "
        f"what could run away. Non-finite values in all rows: {non_finite}. Farthest Gaussian: "
        f"{worst.max_abs['means']:.3g} m ({worst.case}).\n\n" + report.stability_table(stability),
    ]
    if args.ablations:
        base = TrainConfig.load(args.ablation_config)
        steps = args.steps or base.total_steps
        trained = ablations.train_variants(base, steps, args.data, args.out / "ablations")
        results = {
            name: (
                evaluate_lods(
                    AvatarRuntime.load(path, model),
                    frames,
                    test.size,
                    test.background,
                    perceptual,
                    report.ABLATION_LODS,
                    ("fp32",),
                    cut=cut,
                ),
                seconds,
            )
            for name, (path, seconds) in trained.items()
        }
        sections.append(
            f"## Ablations (table 4)\n\nEvery variant trained with config "
            f"`{args.ablation_config}` and {steps} steps (the stages in the config's "
            "proportion), evaluated on the same test frames. The paper's numbers are its own "
            "subjects at its full GPU budget.\n\n" + report.ablation_table(results, steps)
        )
    sections.append(f"Report time: {watch.seconds:.0f} s.")
    path = args.out / "report.md"
    write_bytes_atomic(path, ("\n\n".join(sections) + "\n").encode())
    if args.docs is not None:
        args.docs.mkdir(parents=True, exist_ok=True)
        for name in FIGURES:
            shutil.copyfile(args.out / name, args.docs / name)
        shutil.copyfile(path, args.docs / DOCS_REPORT)
    return path


def main(argv=None) -> int:
    args = parse_args(argv)
    args.argv = sys.argv[1:] if argv is None else list(argv)  # for the report's header
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # see train/__main__.py

    def report():
        path = run(args)
        print(path.read_text())
        print(f"report: {path}")

    return run_command(report)


if __name__ == "__main__":
    sys.exit(main())
